#include "face_reenact/reenact/contact_sheet.h"

#include <algorithm>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"

namespace face_reenact::reenact {
namespace {

cv::Mat scaled_to_height(const cv::Mat& img, int height) {
  cv::Mat out;
  const int width = std::max(1, static_cast<int>(std::lround(double(img.cols) * height / std::max(1, img.rows))));
  cv::resize(img, out, cv::Size(width, height), 0, 0, img.rows < height ? cv::INTER_CUBIC : cv::INTER_AREA);
  return out;
}

void label(cv::Mat* panel, const std::string& text) {
  const int font = cv::FONT_HERSHEY_SIMPLEX;
  int base = 0;
  const cv::Size size = cv::getTextSize(text, font, 0.45, 1, &base);
  cv::rectangle(*panel, cv::Rect(0, 0, std::min(panel->cols, size.width + 6), size.height + base + 6), cv::Scalar(0, 0, 0),
                cv::FILLED);
  cv::putText(*panel, text, cv::Point(3, size.height + 3), font, 0.45, cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
}

}  // namespace

cv::Mat ReenactmentContactSheet(const cv::Mat& source, const cv::Mat& target, const cv::Mat& output,
                                const cv::Mat& face_mask, const std::string& caption, const ContactSheetOptions& o) {
  if (o.panel_height < 16) throw Error("contact sheet: panel_height must be at least 16");
  if (target.type() != CV_8UC3 || output.type() != CV_8UC3 || target.size() != output.size() || target.empty())
    throw Error("contact sheet: the target and the output must be 8-bit colour images of one size");
  if (!source.empty() && source.type() != CV_8UC3) throw Error("contact sheet: the source must be an 8-bit colour image");
  if (!face_mask.empty() && (face_mask.type() != CV_8UC1 || face_mask.size() != output.size()))
    throw Error("contact sheet: the face mask must be 8-bit single-channel, the output's size");
  const int h = o.panel_height;

  cv::Mat src;
  if (source.empty()) {
    src = cv::Mat(h, h * target.cols / std::max(1, target.rows), CV_8UC3, cv::Scalar(60, 60, 60));
    cv::putText(src, "no source image", cv::Point(10, h / 2), cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(220, 220, 220), 1,
                cv::LINE_AA);
    cv::putText(src, "(expression stream)", cv::Point(10, h / 2 + 20), cv::FONT_HERSHEY_SIMPLEX, 0.5,
                cv::Scalar(220, 220, 220), 1, cv::LINE_AA);
  } else {
    src = scaled_to_height(source, h);
  }
  cv::Mat t = scaled_to_height(target, h), out = scaled_to_height(output, h);
  label(&src, "source");
  label(&t, "target");
  label(&out, "output" + (caption.empty() ? std::string() : "  " + caption));

  // The face: the rendered face's box grown by a fifth (a square around the middle of the frame
  // without one); the mouth: its lower two fifths, the middle three quarters of its width.
  const cv::Rect frame(0, 0, output.cols, output.rows);
  cv::Rect face = face_mask.empty() || cv::countNonZero(face_mask) == 0 ? cv::Rect() : cv::boundingRect(face_mask);
  if (face.area() < 16) {
    const int side = std::min(output.cols, output.rows) / 2;
    face = cv::Rect((output.cols - side) / 2, (output.rows - side) / 2, side, side);
  }
  const int gx = face.width / 10, gy = face.height / 10;
  const cv::Rect face_zoom = cv::Rect(face.x - gx, face.y - gy, face.width + 2 * gx, face.height + 2 * gy) & frame;
  const cv::Rect mouth = cv::Rect(face.x + face.width / 8, face.y + face.height * 3 / 5, face.width * 3 / 4,
                                  std::max(1, face.height * 2 / 5)) &
                         frame;
  cv::Mat tf = scaled_to_height(target(face_zoom), h), of = scaled_to_height(output(face_zoom), h),
          om = scaled_to_height(output(mouth), h);
  label(&tf, "target face");
  label(&of, "output face");
  label(&om, "output mouth");

  cv::Mat top, bottom, sheet;
  cv::hconcat(std::vector<cv::Mat>{src, t, out}, top);
  cv::hconcat(std::vector<cv::Mat>{tf, of, om}, bottom);
  const int width = std::max(top.cols, bottom.cols);
  auto pad = [&](const cv::Mat& row) {
    cv::Mat padded;
    cv::copyMakeBorder(row, padded, 0, 0, 0, width - row.cols, cv::BORDER_CONSTANT, cv::Scalar(30, 30, 30));
    return padded;
  };
  cv::vconcat(pad(top), pad(bottom), sheet);
  return sheet;
}

}  // namespace face_reenact::reenact
