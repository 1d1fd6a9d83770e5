#pragma once
// What the tracker needs of the face model: the renderable linear model (core/gpu RenderModel)
// plus the prior standard deviations of Eq. 11 and the landmark vertices of E_lan (Eq. 10).
#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "face_reenact/gpu/image_formation.h"

namespace face_reenact {
struct FaceModel;
}

namespace face_reenact::tracker {

struct TrackerLandmark {
  int32_t ibug_index = 0;  // 0..67, iBUG 300-W order
  int32_t vertex = 0;      // model vertex
  uint8_t flags = 0;       // face_reenact::LandmarkFlag bits
};

struct TrackerModel {
  gpu::RenderModel render;
  Eigen::VectorXf identity_sigma;  // K_id, metres (prior std-dev of alpha_i)
  Eigen::VectorXf albedo_sigma;    // K_alb
  float expression_sigma = 1.0f;   // sigma_exp of Eq. 11 (blendshape weights in [0, 1])
  std::vector<TrackerLandmark> landmarks;

  int num_identity() const { return static_cast<int>(render.identity_basis.cols()); }
  int num_expression() const { return static_cast<int>(render.expression_basis.cols()); }
  int num_albedo() const { return static_cast<int>(render.albedo_basis.cols()); }
  int num_vertices() const { return render.num_vertices(); }

  bool IsValid(std::string* why) const;
  static TrackerModel FromFaceModel(const FaceModel& model);
};

}  // namespace face_reenact::tracker
