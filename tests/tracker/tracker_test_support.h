#pragma once
// Shared fixtures of the tracker tests: the real face model when one is built (FR_MODEL, which
// tests/test_main.cc defaults to the build's model), a deformable test sphere otherwise, and
// synthetic ground truth.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <random>
#include <string>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/tracker/tracker_model.h"
#include "test_meshes.h"

namespace face_reenact::tracker::testing {

inline std::string real_model_path() {
  const char* path = std::getenv("FR_MODEL");
  return path && *path && std::filesystem::exists(path) ? path : std::string();
}

// The real model, loaded once; nullptr when none is built yet.
inline const TrackerModel* real_model() {
  static std::unique_ptr<TrackerModel> model = [] {
    const std::string path = real_model_path();
    if (path.empty()) return std::unique_ptr<TrackerModel>();
    return std::make_unique<TrackerModel>(TrackerModel::FromFaceModel(load_face_model(path)));
  }();
  return model.get();
}

// A 10 cm sphere with smooth random identity/expression/albedo fields and 12 landmark vertices
// on the side that faces the camera in frontal_pose (model +z).
inline TrackerModel sphere_model() {
  TrackerModel m;
  m.render = gpu::testing::make_deformable_sphere(0.1f, 3, 6, 5, 4, 7);
  m.identity_sigma = Eigen::VectorXf::Constant(6, 0.01f);
  m.albedo_sigma = Eigen::VectorXf::Constant(4, 0.1f);
  m.expression_sigma = 1.0f;
  int next = 0;
  for (int v = 0; v < m.render.num_vertices() && next < 12; v += 7) {
    if (m.render.mean_shape[3 * v + 2] > 0.06f) {
      m.landmarks.push_back({next + 48, v, kLandmarkInner});  // 48..59: inner (mouth) indices
      ++next;
    }
  }
  return m;
}

inline gpu::PinholeCamera test_camera(int width = 640, int height = 480) {
  gpu::PinholeCamera c;
  c.width = width;
  c.height = height;
  c.fx = c.fy = 525.0f * width / 640.0f;
  c.cx = (width - 1) * 0.5f;
  c.cy = (height - 1) * 0.5f;
  return c;
}

// Ground truth: a face `distance` m away, slightly turned, a few expressions, coloured light.
inline gpu::FaceParameters true_parameters(const TrackerModel& m, float distance, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  gpu::FaceParameters p = gpu::frontal_pose(distance);
  p.alpha = Eigen::VectorXf::Zero(m.num_identity());
  for (int k = 0; k < m.num_identity(); ++k) p.alpha[k] = 0.7f * u(rng) * m.identity_sigma[k];
  p.beta = Eigen::VectorXf::Zero(m.num_albedo());
  for (int k = 0; k < m.num_albedo(); ++k) p.beta[k] = 0.7f * u(rng) * m.albedo_sigma[k];
  p.delta = Eigen::VectorXf::Zero(m.num_expression());
  for (int k = 0; k < m.num_expression(); k += 5) p.delta[k] = 0.2f + 0.3f * std::abs(u(rng));
  p.euler += Eigen::Vector3f(0.06f, 0.12f, -0.04f);
  p.translation += Eigen::Vector3f(0.01f, -0.008f, 0.0f);
  p.gamma = gpu::ambient_sh(Eigen::Vector3f(0.9f, 0.85f, 0.8f));
  for (int c = 0; c < 3; ++c) {
    p.gamma[c * 9 + 1] = -0.25f;  // light from above (y down in the camera frame)
    p.gamma[c * 9 + 3] = 0.15f;
    p.gamma[c * 9 + 2] = -0.2f;   // and from the camera side
  }
  return p;
}

// Runs a shell command (the CLI tests use redirections such as 2>&1) and returns its stdout;
// *status receives pclose's wait status.
// The angle (rad) between the rotations of `a` and `b`, from the sine (the skew part of
// R_a^T R_b) and the cosine, in double: acos of the trace alone, in float, reads any angle below
// 2^-11 rad (0.028 deg) as 0 or 2^-11.
inline double rotation_error(const gpu::FaceParameters& a, const gpu::FaceParameters& b) {
  const Eigen::Matrix3d d = gpu::rotation_from_euler(a.euler).cast<double>().transpose() *
                            gpu::rotation_from_euler(b.euler).cast<double>();
  const Eigen::Vector3d sine(d(2, 1) - d(1, 2), d(0, 2) - d(2, 0), d(1, 0) - d(0, 1));
  return std::atan2(0.5 * sine.norm(), 0.5 * (d.trace() - 1.0));
}

inline std::string run_shell_command(const std::string& command, int* status) {
  std::string out;
  FILE* pipe = popen(command.c_str(), "r");
  if (!pipe) return out;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof(buf), pipe)) > 0) out.append(buf, n);
  *status = pclose(pipe);
  return out;
}

}  // namespace face_reenact::tracker::testing
