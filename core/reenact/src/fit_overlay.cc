#include "face_reenact/reenact/fit_overlay.h"

#include <cmath>
#include <cstdio>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"

namespace face_reenact::reenact {

bool FitOverlayOptions::IsValid(std::string* why) const {
  if (!(mesh_opacity > 0.f && mesh_opacity <= 1.f)) {
    if (why) *why = "overlay: mesh_opacity must be in (0, 1]";
    return false;
  }
  if (!(min_landmark_confidence >= 0.f && min_landmark_confidence < 1.f)) {
    if (why) *why = "overlay: min_landmark_confidence must be in [0, 1)";
    return false;
  }
  return true;
}

std::string OverlayStatusLine(const std::string& status, double pose_disagreement_deg, double landmark_nme) {
  std::string line = status;
  char buf[96];
  if (std::isfinite(pose_disagreement_deg)) {
    std::snprintf(buf, sizeof buf, " | pose %.1f deg off", pose_disagreement_deg);
    line += buf;
  }
  if (std::isfinite(landmark_nme)) {
    std::snprintf(buf, sizeof buf, " | points %.1f%% of eye dist.", 100 * landmark_nme);
    line += buf;
  }
  return line;
}

void DrawFitOverlay(cv::Mat* bgr, const tracker::TrackerModel& model, const gpu::CpuRenderer& renderer,
                    const gpu::PinholeCamera& camera, const gpu::FaceParameters* params,
                    const std::vector<tracker::InputLandmark>& detected, const std::string& status,
                    const FitOverlayOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  if (!bgr || bgr->type() != CV_8UC3 || bgr->cols != camera.width || bgr->rows != camera.height)
    throw Error("overlay: the image must be 8-bit BGR of the camera's size");
  // Lines and dots scale with the image, so they read the same at 320x240 and 1080p.
  const double scale = std::max(1.0, camera.width / 640.0);
  const int thickness = static_cast<int>(std::lround(scale));
  const int shift = 4;  // sub-pixel precision of the drawn coordinates (1/16 px)
  auto fixed_point = [&](const Eigen::Vector2f& p) {
    return cv::Point(static_cast<int>(std::lround(p.x() * (1 << shift))), static_cast<int>(std::lround(p.y() * (1 << shift))));
  };
  auto inside = [&](const Eigen::Vector2f& p) {
    return std::abs(p.x()) < 1e5f && std::abs(p.y()) < 1e5f;  // far-off points would overflow fixed point
  };
  const bool fit = params != nullptr && params->euler.allFinite() && params->translation.allFinite();
  std::vector<Eigen::Vector2f> projected;
  if (fit) {
    const gpu::VertexState state = renderer.evaluate(*params);
    const int n = static_cast<int>(state.camera_positions.size() / 3);
    projected.resize(static_cast<size_t>(n), Eigen::Vector2f::Constant(std::nanf("")));
    for (int v = 0; v < n; ++v) {
      const Eigen::Vector3f x = state.camera_positions.segment<3>(3 * v);
      if (x.z() > camera.near_plane) projected[static_cast<size_t>(v)] = {camera.fx * x.x() / x.z() + camera.cx, camera.fy * x.y() / x.z() + camera.cy};
    }
    if (options.mesh) {
      // Visible triangles: those the rasteriser kept for at least one pixel (occlusion and
      // back faces resolved as in the tracker's own render).
      const gpu::GBuffer g = renderer.rasterize(state, camera, gpu::RenderOptions());
      std::vector<uint8_t> visible(renderer.model().triangles.size(), 0);
      for (int32_t t : g.triangle)
        if (t >= 0) visible[static_cast<size_t>(t)] = 1;
      cv::Mat layer = bgr->clone();
      const auto& parts = renderer.model().vertex_part;
      for (size_t t = 0; t < visible.size(); ++t) {
        if (!visible[t]) continue;
        const auto& tri = renderer.model().triangles[t];
        const bool face = parts[static_cast<size_t>(tri[0])] == static_cast<uint8_t>(FacePart::Face);
        const cv::Scalar colour = face ? cv::Scalar(255, 230, 60) : cv::Scalar(200, 120, 40);  // BGR: cyan / blue
        for (int e = 0; e < 3; ++e) {
          const Eigen::Vector2f& a = projected[static_cast<size_t>(tri[e])];
          const Eigen::Vector2f& b = projected[static_cast<size_t>(tri[(e + 1) % 3])];
          if (!inside(a) || !inside(b)) continue;
          cv::line(layer, fixed_point(a), fixed_point(b), colour, 1, cv::LINE_AA, shift);
        }
      }
      cv::addWeighted(layer, options.mesh_opacity, *bgr, 1.0 - options.mesh_opacity, 0.0, *bgr);
    }
  }
  if (options.landmarks) {
    const int radius = static_cast<int>(std::lround(2 * scale)) << shift;
    for (const auto& l : detected) {
      if (!(l.confidence > options.min_landmark_confidence) || !inside(l.position)) continue;
      cv::circle(*bgr, fixed_point(l.position), radius, cv::Scalar(60, 220, 60), cv::FILLED, cv::LINE_AA, shift);
    }
    if (fit) {
      for (const auto& l : model.landmarks) {
        const Eigen::Vector2f& p = projected[static_cast<size_t>(l.vertex)];
        if (!inside(p)) continue;
        cv::circle(*bgr, fixed_point(p), radius, cv::Scalar(40, 40, 230), thickness, cv::LINE_AA, shift);
      }
    }
  }
  if (!status.empty()) {
    const double font = 0.45 * scale;
    int baseline = 0;
    const cv::Size size = cv::getTextSize(status, cv::FONT_HERSHEY_SIMPLEX, font, thickness, &baseline);
    const int pad = static_cast<int>(4 * scale);
    cv::rectangle(*bgr, cv::Rect(0, 0, std::min(bgr->cols, size.width + 2 * pad), size.height + baseline + 2 * pad),
                  cv::Scalar(0, 0, 0), cv::FILLED);
    cv::putText(*bgr, status, cv::Point(pad, pad + size.height), cv::FONT_HERSHEY_SIMPLEX, font, cv::Scalar(255, 255, 255),
                thickness, cv::LINE_AA);
  }
}

}  // namespace face_reenact::reenact
