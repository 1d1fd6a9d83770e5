#pragma once
// A small, internally consistent FaceModel for exercising the file format and loaders. It is
// random test data for the container, not face data: tests about faces use the real model.
#include <Eigen/QR>
#include <random>

#include "face_reenact/model/face_model.h"

namespace face_reenact::testing {

inline FaceModel make_small_model(uint32_t seed, int n = 12, int k_id = 5, int k_alb = 3) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> g;
  FaceModel m;
  for (int i = 0; i < n; ++i) {
    m.vertex_part.push_back(static_cast<FacePart>(i % kNumFaceParts));
    m.mirror_vertex.push_back(n - 1 - i);
    m.base_vertex.push_back(1000 + i);
  }
  for (int i = 0; i + 2 < n; ++i) {
    m.triangles.push_back({i, i + 1, i + 2});
    for (int c = 0; c < 3; ++c) m.corner_uvs.push_back({0.1f * c, 0.01f * i});
  }
  auto rand_mat = [&](int r, int c) {
    Eigen::MatrixXf x(r, c);
    for (int j = 0; j < x.size(); ++j) x.data()[j] = g(rng);
    return x;
  };
  m.mean_shape = rand_mat(3 * n, 1).col(0);
  m.identity_basis = rand_mat(3 * n, k_id).householderQr().householderQ() * Eigen::MatrixXf::Identity(3 * n, k_id);
  m.identity_sigma.resize(k_id);
  for (int i = 0; i < k_id; ++i) m.identity_sigma[i] = 0.01f / float(i + 1);
  m.identity_explained_variance = 0.996f;
  m.expression_basis = rand_mat(3 * n, 52) * 0.001f;
  for (auto* name : arkit_blendshape_names()) m.expression_names.push_back(name);
  m.mean_albedo = Eigen::VectorXf::Constant(3 * n, 0.5f);
  m.albedo_basis = rand_mat(3 * n, k_alb).householderQr().householderQ() * Eigen::MatrixXf::Identity(3 * n, k_alb);
  m.albedo_sigma = Eigen::VectorXf::Constant(k_alb, 0.1f);
  for (int i = 0; i < k_alb; ++i) m.albedo_names.push_back("component_" + std::to_string(i));
  for (int i = 0; i < std::min(n, 68); ++i) m.landmarks.push_back({i, i, uint8_t(i % 4)});
  m.source = "unit test";
  m.source_sha256 = "00";
  m.identity_samples = 7;
  m.build_seed = seed;
  return m;
}

}  // namespace face_reenact::testing
