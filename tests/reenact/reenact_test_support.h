#pragma once
// Shared helpers of the reenactment tests: the face model and target frames rendered by the
// CPU renderer (no Vulkan, no files besides the model).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "face_reenact/common/srgb.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/reenact/reenactment_pipeline.h"
#include "face_reenact/tracker/solver.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::reenact::testing {

inline const FaceModel* test_model() {
  static std::unique_ptr<FaceModel> model = []() -> std::unique_ptr<FaceModel> {
    const char* path = std::getenv("FR_MODEL");
    if (!path || !std::filesystem::exists(path)) return nullptr;
    return std::make_unique<FaceModel>(load_face_model(path));
  }();
  return model.get();
}

#define FR_REQUIRE_MODEL()                                                                                   \
  do {                                                                                                       \
    const char* m_ = std::getenv("FR_MODEL");                                                                \
    ASSERT_NE(::face_reenact::reenact::testing::test_model(), nullptr)                                       \
        << "face model missing (FR_MODEL='" << (m_ ? m_ : "") << "'): build it with `face-reenact model build`"; \
  } while (0)

// Kinect-like intrinsics scaled to w x h.
inline gpu::PinholeCamera test_camera(int w, int h) {
  gpu::PinholeCamera c;
  const float s = static_cast<float>(w) / 640.0f;
  c.fx = c.fy = 525.0f * s;
  c.cx = (static_cast<float>(w) - 1.0f) / 2.0f;
  c.cy = (static_cast<float>(h) - 1.0f) / 2.0f;
  c.width = w;
  c.height = h;
  return c;
}

// A lit face at `distance` m: ambient plus a light from the upper left, warm tint.
inline gpu::FaceParameters test_face(float distance) {
  gpu::FaceParameters p = gpu::frontal_pose(distance);
  p.delta = Eigen::VectorXf::Zero(52);
  for (int c = 0; c < 3; ++c) {
    const float tint = c == 0 ? 1.05f : (c == 1 ? 1.0f : 0.92f);
    p.gamma[static_cast<size_t>(c * 9 + 0)] = 2.6f * tint;
    p.gamma[static_cast<size_t>(c * 9 + 1)] = -0.5f * tint;  // y: from above (y down)
    p.gamma[static_cast<size_t>(c * 9 + 3)] = -0.4f * tint;  // x: from the left
    p.gamma[static_cast<size_t>(c * 9 + 2)] = -0.6f * tint;  // z: from the camera side
  }
  return p;
}

// The default options but for the albedo map's appearance (the whole face re-rendered, the mouth
// interior at full strength wherever the rendered mouth opens).
inline ReenactmentOptions albedo_map_options() {
  ReenactmentOptions o;
  o.appearance = Appearance::kAlbedoMap;
  return o;
}

// The model vertices of iBUG landmarks first..last, in that order (the inner lips: 60, 67).
inline std::vector<int32_t> landmark_vertices(const FaceModel& model, int first, int last) {
  std::vector<int32_t> out;
  for (int k = first; k <= last; ++k)
    for (const auto& l : model.landmarks)
      if (l.ibug_index == k) out.push_back(l.vertex);
  return out;
}

// Where vertices of an evaluated face project, rounded to pixels.
inline std::vector<cv::Point> project_vertices(const gpu::VertexState& state, const gpu::PinholeCamera& cam,
                                               const std::vector<int32_t>& vertices) {
  std::vector<cv::Point> out;
  for (int32_t v : vertices) {
    const Eigen::Vector3f x = state.camera_positions.segment<3>(3 * v);
    out.emplace_back(static_cast<int>(std::lround(cam.fx * x.x() / x.z() + cam.cx)),
                     static_cast<int>(std::lround(cam.fy * x.y() / x.z() + cam.cy)));
  }
  return out;
}

// Points rounded to the nearest pixel: a polygon for cv::fillPoly (e.g. FaceCompositor::MouthOpening's).
inline std::vector<cv::Point> pixel_polygon(const std::vector<Eigen::Vector2f>& points) {
  std::vector<cv::Point> out;
  for (const auto& v : points) out.emplace_back(static_cast<int>(std::lround(v.x())), static_cast<int>(std::lround(v.y())));
  return out;
}

// The test model as the tracker sees it, and a CPU renderer of it (made once per test program).
inline const tracker::TrackerModel& test_tracker_model() {
  static const tracker::TrackerModel tmodel = tracker::TrackerModel::FromFaceModel(*test_model());
  return tmodel;
}
inline const gpu::CpuRenderer& test_renderer() {
  static const gpu::CpuRenderer renderer(test_tracker_model().render);
  return renderer;
}

// The mean absolute difference of two 8-bit BGR images over `mask`, averaged over the channels.
inline double mean_abs_diff(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  cv::Mat d;
  cv::absdiff(a, b, d);
  const cv::Scalar m = cv::mean(d, mask);
  return (m[0] + m[1] + m[2]) / 3.0;
}

// The CPU renderer's image of `params` (skin parts over a grey background) as 8-bit sRGB BGR.
inline cv::Mat render_target(const gpu::FaceParameters& params, const gpu::PinholeCamera& camera) {
  const tracker::InputFrame f =
      tracker::RenderSyntheticFrame(test_renderer(), test_tracker_model(), params, camera, {}, 0.25f);
  cv::Mat bgr(camera.height, camera.width, CV_8UC3);
  for (int j = 0; j < camera.height; ++j)
    for (int i = 0; i < camera.width; ++i) {
      const size_t p = (static_cast<size_t>(j) * camera.width + i) * 3;
      cv::Vec3b& px = bgr.at<cv::Vec3b>(j, i);
      for (int c = 0; c < 3; ++c) px[2 - c] = cv::saturate_cast<uchar>(255.0f * srgb_encode(f.color[p + static_cast<size_t>(c)]));
    }
  return bgr;
}

// `image` with a per-pixel pattern of +-18 levels added (seeded): a stand-in for pores, stubble and
// the camera's grain, finer than the mesh.
inline cv::Mat with_fine_pattern(const cv::Mat& image, int seed = 7) {
  cv::Mat pattern(image.size(), CV_16SC3);
  cv::RNG rng(static_cast<uint64_t>(seed));
  rng.fill(pattern, cv::RNG::UNIFORM, cv::Scalar::all(-18), cv::Scalar::all(19));
  cv::Mat detailed;
  cv::add(image, pattern, detailed, cv::noArray(), CV_8UC3);
  return detailed;
}

}  // namespace face_reenact::reenact::testing
