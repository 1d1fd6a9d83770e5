#pragma once
// The unknowns of the Gauss-Newton solve as one vector x, in block order
//   [alpha (identity) | beta (albedo) | delta (expression) | gamma (27 SH) | euler (3) | t (3)],
// where identity and albedo are present only when solved (calibration, Sec. 6.3); while
// tracking they are fixed at the values of a base FaceParameters.
#include <Eigen/Core>
#include <array>
#include <string>

#include "face_reenact/gpu/image_formation.h"

namespace face_reenact::tracker {

enum class Block { kIdentity = 0, kAlbedo, kExpression, kLighting, kRotation, kTranslation };
inline constexpr int kNumBlocks = 6;
const char* block_name(Block b);

struct ParameterLayout {
  int num_identity = 0;    // alpha entries solved (the first ones of the model)
  int num_albedo = 0;      // beta entries solved
  int num_expression = 0;  // delta entries solved (normally all of the model's)

  // Tracking: expression, lighting and pose. Calibration: also `identity` / `albedo` components.
  static ParameterLayout Tracking(int num_expression);
  static ParameterLayout Calibration(int num_identity, int num_albedo, int num_expression);

  int offset(Block b) const;
  int size(Block b) const;
  int num_parameters() const { return offset(Block::kTranslation) + 3; }

  // x from P (missing trailing coefficients of P are zero).
  Eigen::VectorXd Pack(const gpu::FaceParameters& params) const;
  // P from x; blocks not in x (and coefficients beyond the solved ones) come from `base`.
  gpu::FaceParameters Unpack(const Eigen::VectorXd& x, const gpu::FaceParameters& base) const;
  bool IsValid(std::string* why, int model_identity, int model_albedo, int model_expression) const;
};

}  // namespace face_reenact::tracker
