// The commands' mp4 writer (plugin/cli/video_output.h): what it writes, read back by OpenCV's
// FFmpeg reader as any player would, and its errors.
#include <gtest/gtest.h>

#include <filesystem>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <vector>

#include "face_reenact/common/error.h"
#include "support/temp_dir.h"
#include "video_output.h"

namespace face_reenact::cli {
namespace {

namespace fs = std::filesystem;

// A frame a codec cannot cheat on: a smooth gradient, a red, a green and a blue patch, and a
// white square that moves 7 px per frame.
cv::Mat test_frame(cv::Size size, int index) {
  cv::Mat f(size, CV_8UC3);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x)
      f.at<cv::Vec3b>(y, x) = cv::Vec3b(static_cast<uchar>(40 + 150 * x / size.width), static_cast<uchar>(60 + 100 * y / size.height), 90);
  const int w = size.width / 6, h = size.height / 5;
  f(cv::Rect(w, h, w, h)).setTo(cv::Scalar(30, 30, 220));          // red (BGR)
  f(cv::Rect(3 * w, h, w, h)).setTo(cv::Scalar(40, 200, 40));      // green
  f(cv::Rect(w, 3 * h, w, h)).setTo(cv::Scalar(210, 60, 30));      // blue
  const int x = (7 * index) % std::max(1, size.width - w);
  f(cv::Rect(x, 4 * h, w / 2, h / 2)).setTo(cv::Scalar(250, 250, 250));
  return f;
}

std::vector<cv::Mat> read_back(const fs::path& file, double* fps) {
  cv::VideoCapture video(file.string(), cv::CAP_FFMPEG);
  EXPECT_TRUE(video.isOpened()) << file;
  if (fps) *fps = video.get(cv::CAP_PROP_FPS);
  std::vector<cv::Mat> frames;
  cv::Mat f;
  while (video.read(f)) frames.push_back(f.clone());
  return frames;
}

TEST(Mp4Writer, WritesEveryFrameAtItsRateWithItsColours) {
  const face_reenact::testing::TempDir dir("fr-mp4-writer");
  const fs::path file = fs::path(dir.path()) / "out.mp4";
  const cv::Size size(640, 480);
  const int count = 24;
  std::string codec;
  {
    Mp4Writer writer(file.string(), 15.0, size);
    codec = writer.codec();
    for (int i = 0; i < count; ++i) writer.write(test_frame(size, i));
    writer.close();
  }
  EXPECT_NE(codec.find("h264"), std::string::npos) << codec;  // Debian's FFmpeg has libx264
  double fps = 0;
  const std::vector<cv::Mat> frames = read_back(file, &fps);
  ASSERT_EQ(frames.size(), static_cast<size_t>(count));
  EXPECT_NEAR(fps, 15.0, 1e-6);
  for (int i = 0; i < count; ++i) {
    ASSERT_EQ(frames[i].size(), size);
    const cv::Mat expected = test_frame(size, i);
    // Frame i is frame i (no frame dropped, doubled or reordered): the moving square is where it was.
    EXPECT_GT(cv::PSNR(frames[i], expected), 38.0) << "frame " << i;
    if (i > 0) EXPECT_GT(cv::PSNR(frames[i], expected), cv::PSNR(frames[i], test_frame(size, i - 1)) + 3.0) << i;
  }
  // The patches keep their colours (red is not blue: the conversion's channel order and range).
  const cv::Mat& last = frames.back();
  const int w = size.width / 6, h = size.height / 5;
  const cv::Scalar red = cv::mean(last(cv::Rect(w + 8, h + 8, w - 16, h - 16)));
  const cv::Scalar blue = cv::mean(last(cv::Rect(w + 8, 3 * h + 8, w - 16, h - 16)));
  for (int c = 0; c < 3; ++c) {
    const double red_bgr[3] = {30, 30, 220}, blue_bgr[3] = {210, 60, 30};
    EXPECT_NEAR(red[c], red_bgr[c], 6.0) << c;
    EXPECT_NEAR(blue[c], blue_bgr[c], 6.0) << c;
  }
}

// 4:2:0 video has even sides: an odd-sized picture (a cropped still) grows by its last row or
// column rather than failing or losing one.
TEST(Mp4Writer, AnOddSizedPictureGrowsByARepeatedEdge) {
  const face_reenact::testing::TempDir dir("fr-mp4-writer");
  const fs::path file = fs::path(dir.path()) / "odd.mp4";
  const cv::Size size(321, 241);
  {
    Mp4Writer writer(file.string(), 30.0, size);
    for (int i = 0; i < 5; ++i) writer.write(test_frame(size, i));
    // No close(): the destructor finishes the file.
  }
  const std::vector<cv::Mat> frames = read_back(file, nullptr);
  ASSERT_EQ(frames.size(), 5u);
  ASSERT_EQ(frames[0].size(), cv::Size(322, 242));
  EXPECT_GT(cv::PSNR(frames[4](cv::Rect(cv::Point(0, 0), size)), test_frame(size, 4)), 36.0);
}

TEST(Mp4Writer, BadPathsSizesAndOrderAreClearErrors) {
  const face_reenact::testing::TempDir dir("fr-mp4-writer");
  EXPECT_THROW(Mp4Writer((fs::path(dir.path()) / "absent" / "x.mp4").string(), 15.0, cv::Size(64, 48)), Error);
  EXPECT_THROW(Mp4Writer((fs::path(dir.path()) / "x.mp4").string(), 0.0, cv::Size(64, 48)), Error);
  EXPECT_THROW(Mp4Writer((fs::path(dir.path()) / "x.mp4").string(), 15.0, cv::Size(0, 48)), Error);
  Mp4Writer writer((fs::path(dir.path()) / "x.mp4").string(), 15.0, cv::Size(64, 48));
  try {
    writer.write(cv::Mat(40, 64, CV_8UC3, cv::Scalar::all(0)));
    ADD_FAILURE() << "a frame of another size was taken";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("expected 64x48"), std::string::npos) << e.what();
  }
  EXPECT_THROW(writer.write(cv::Mat(48, 64, CV_8UC1, cv::Scalar::all(0))), Error);  // grey is not BGR
  writer.write(cv::Mat(48, 64, CV_8UC3, cv::Scalar::all(100)));
  writer.close();
  writer.close();  // a second close is nothing
  EXPECT_THROW(writer.write(cv::Mat(48, 64, CV_8UC3, cv::Scalar::all(0))), Error);
  EXPECT_EQ(read_back(fs::path(dir.path()) / "x.mp4", nullptr).size(), 1u);
}

}  // namespace
}  // namespace face_reenact::cli
