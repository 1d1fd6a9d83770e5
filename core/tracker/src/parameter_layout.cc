#include "face_reenact/tracker/parameter_layout.h"

#include <algorithm>

#include "face_reenact/common/error.h"

namespace face_reenact::tracker {

const char* block_name(Block b) {
  switch (b) {
    case Block::kIdentity: return "identity";
    case Block::kAlbedo: return "albedo";
    case Block::kExpression: return "expression";
    case Block::kLighting: return "lighting";
    case Block::kRotation: return "rotation";
    case Block::kTranslation: return "translation";
  }
  return "?";
}

ParameterLayout ParameterLayout::Tracking(int num_expression) { return {0, 0, num_expression}; }

ParameterLayout ParameterLayout::Calibration(int num_identity, int num_albedo, int num_expression) {
  return {num_identity, num_albedo, num_expression};
}

int ParameterLayout::size(Block b) const {
  switch (b) {
    case Block::kIdentity: return num_identity;
    case Block::kAlbedo: return num_albedo;
    case Block::kExpression: return num_expression;
    case Block::kLighting: return gpu::kNumShParameters;
    case Block::kRotation: return 3;
    case Block::kTranslation: return 3;
  }
  return 0;
}

int ParameterLayout::offset(Block b) const {
  int o = 0;
  for (int k = 0; k < static_cast<int>(b); ++k) o += size(static_cast<Block>(k));
  return o;
}

bool ParameterLayout::IsValid(std::string* why, int model_identity, int model_albedo, int model_expression) const {
  auto check = [&](int n, int max, const char* what) {
    if (n < 0 || n > max) {
      if (why) *why = std::string("parameter layout: ") + what + " count " + std::to_string(n) + " outside 0.." + std::to_string(max);
      return false;
    }
    return true;
  };
  return check(num_identity, model_identity, "identity") && check(num_albedo, model_albedo, "albedo") &&
         check(num_expression, model_expression, "expression");
}

Eigen::VectorXd ParameterLayout::Pack(const gpu::FaceParameters& p) const {
  Eigen::VectorXd x = Eigen::VectorXd::Zero(num_parameters());
  auto put = [&](Block b, const Eigen::VectorXf& v) {
    const int n = std::min<int>(size(b), static_cast<int>(v.size()));
    x.segment(offset(b), n) = v.head(n).cast<double>();
  };
  put(Block::kIdentity, p.alpha);
  put(Block::kAlbedo, p.beta);
  put(Block::kExpression, p.delta);
  for (int k = 0; k < gpu::kNumShParameters; ++k) x[offset(Block::kLighting) + k] = p.gamma[k];
  x.segment<3>(offset(Block::kRotation)) = p.euler.cast<double>();
  x.segment<3>(offset(Block::kTranslation)) = p.translation.cast<double>();
  return x;
}

gpu::FaceParameters ParameterLayout::Unpack(const Eigen::VectorXd& x, const gpu::FaceParameters& base) const {
  if (x.size() != num_parameters()) throw Error("parameter vector has the wrong size for its layout");
  gpu::FaceParameters p = base;
  auto take = [&](Block b, Eigen::VectorXf* v) {
    const int n = size(b);
    if (n == 0) return;
    if (v->size() < n) {
      Eigen::VectorXf grown = Eigen::VectorXf::Zero(n);
      grown.head(v->size()) = *v;
      *v = grown;
    }
    v->head(n) = x.segment(offset(b), n).cast<float>();
  };
  take(Block::kIdentity, &p.alpha);
  take(Block::kAlbedo, &p.beta);
  take(Block::kExpression, &p.delta);
  for (int k = 0; k < gpu::kNumShParameters; ++k) p.gamma[k] = static_cast<float>(x[offset(Block::kLighting) + k]);
  p.euler = x.segment<3>(offset(Block::kRotation)).cast<float>();
  p.translation = x.segment<3>(offset(Block::kTranslation)).cast<float>();
  return p;
}

}  // namespace face_reenact::tracker
