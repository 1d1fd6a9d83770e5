#include "face_reenact/model/face_model.h"

#include <cmath>
#include <set>

namespace face_reenact {

const char* face_part_name(FacePart p) {
  switch (p) {
    case FacePart::Face: return "face";
    case FacePart::Scalp: return "scalp";
    case FacePart::Ear: return "ear";
    case FacePart::Neck: return "neck";
    case FacePart::UpperTeeth: return "upper_teeth";
    case FacePart::LowerTeeth: return "lower_teeth";
    case FacePart::Tongue: return "tongue";
    case FacePart::LeftEye: return "left_eye";
    case FacePart::RightEye: return "right_eye";
  }
  return "unknown";
}

const std::array<const char*, 52>& arkit_blendshape_names() {
  // ARKit's ARFaceAnchor.BlendShapeLocation order as streamed by Live Link Face.
  static const std::array<const char*, 52> kNames = {
      "eyeBlinkLeft",     "eyeLookDownLeft",   "eyeLookInLeft",     "eyeLookOutLeft",
      "eyeLookUpLeft",    "eyeSquintLeft",     "eyeWideLeft",       "eyeBlinkRight",
      "eyeLookDownRight", "eyeLookInRight",    "eyeLookOutRight",   "eyeLookUpRight",
      "eyeSquintRight",   "eyeWideRight",      "jawForward",        "jawRight",
      "jawLeft",          "jawOpen",           "mouthClose",        "mouthFunnel",
      "mouthPucker",      "mouthRight",        "mouthLeft",         "mouthSmileLeft",
      "mouthSmileRight",  "mouthFrownLeft",    "mouthFrownRight",   "mouthDimpleLeft",
      "mouthDimpleRight", "mouthStretchLeft",  "mouthStretchRight", "mouthRollLower",
      "mouthRollUpper",   "mouthShrugLower",   "mouthShrugUpper",   "mouthPressLeft",
      "mouthPressRight",  "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
      "mouthUpperUpRight", "browDownLeft",     "browDownRight",     "browInnerUp",
      "browOuterUpLeft",  "browOuterUpRight",  "cheekPuff",         "cheekSquintLeft",
      "cheekSquintRight", "noseSneerLeft",     "noseSneerRight",    "tongueOut"};
  return kNames;
}

int arkit_blendshape_index(const std::string& name) {
  const auto& names = arkit_blendshape_names();
  for (size_t i = 0; i < names.size(); ++i)
    if (name == names[i]) return static_cast<int>(i);
  return -1;
}

const std::array<std::array<const char*, 4>, 2>& arkit_eye_look_names() {
  static const std::array<std::array<const char*, 4>, 2> names{
      {{"eyeLookOutLeft", "eyeLookInLeft", "eyeLookUpLeft", "eyeLookDownLeft"},
       {"eyeLookOutRight", "eyeLookInRight", "eyeLookUpRight", "eyeLookDownRight"}}};
  return names;
}

Eigen::VectorXf FaceModel::shape(const Eigen::VectorXf& alpha, const Eigen::VectorXf& delta) const {
  Eigen::VectorXf s = mean_shape;
  const Eigen::Index ka = std::min<Eigen::Index>(alpha.size(), identity_basis.cols());
  if (ka > 0) s.noalias() += identity_basis.leftCols(ka) * alpha.head(ka);
  if (delta.size() > 0) s.noalias() += expression_basis * delta;
  return s;
}

Eigen::VectorXf FaceModel::part_weights(FacePart part) const {
  Eigen::VectorXf w(num_vertices());
  for (int v = 0; v < num_vertices(); ++v) w[v] = vertex_part[v] == part ? 1.f : 0.f;
  return w;
}

Eigen::VectorXf FaceModel::albedo(const Eigen::VectorXf& beta) const {
  Eigen::VectorXf a = mean_albedo;
  const Eigen::Index kb = std::min<Eigen::Index>(beta.size(), albedo_basis.cols());
  if (kb > 0) a.noalias() += albedo_basis.leftCols(kb) * beta.head(kb);
  return a;
}

bool FaceModel::IsValid(std::string* why) const {
  auto bad = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  const Eigen::Index n = num_vertices();
  if (n <= 0) return bad("model has no vertices");
  if (mirror_vertex.size() != static_cast<size_t>(n) || base_vertex.size() != static_cast<size_t>(n))
    return bad("per-vertex arrays disagree on the vertex count");
  if (mean_shape.size() != 3 * n) return bad("mean shape has wrong size");
  if (identity_basis.rows() != 3 * n || identity_sigma.size() != identity_basis.cols())
    return bad("identity basis/sigma sizes inconsistent");
  if (expression_basis.rows() != 3 * n ||
      expression_names.size() != static_cast<size_t>(expression_basis.cols()))
    return bad("expression basis/names sizes inconsistent");
  if (mean_albedo.size() != 3 * n || albedo_basis.rows() != 3 * n ||
      albedo_sigma.size() != albedo_basis.cols() ||
      albedo_names.size() != static_cast<size_t>(albedo_basis.cols()))
    return bad("albedo sizes inconsistent");
  if (corner_uvs.size() != 3 * triangles.size()) return bad("corner UV count is not 3 per triangle");
  for (const auto& t : triangles)
    for (int v : t)
      if (v < 0 || v >= n) return bad("triangle index out of range");
  for (size_t i = 0; i < mirror_vertex.size(); ++i)
    if (mirror_vertex[i] < 0 || mirror_vertex[i] >= n) return bad("mirror index out of range");
  for (auto p : vertex_part)
    if (static_cast<int>(p) >= kNumFaceParts) return bad("unknown vertex part");
  std::set<int> seen;
  for (const auto& l : landmarks) {
    if (l.vertex < 0 || l.vertex >= n) return bad("landmark vertex out of range");
    if (l.ibug_index < 0 || l.ibug_index > 67 || !seen.insert(l.ibug_index).second)
      return bad("landmark iBUG index out of range or repeated");
  }
  if (!mean_shape.allFinite() || !identity_basis.allFinite() || !identity_sigma.allFinite() ||
      !expression_basis.allFinite() || !mean_albedo.allFinite() || !albedo_basis.allFinite() ||
      !albedo_sigma.allFinite())
    return bad("model contains NaN or infinite values");
  for (Eigen::Index i = 0; i < identity_sigma.size(); ++i) {
    if (!(identity_sigma[i] > 0)) return bad("identity sigma must be positive");
    if (i > 0 && identity_sigma[i] > identity_sigma[i - 1]) return bad("identity sigma not sorted");
  }
  for (Eigen::Index i = 0; i < albedo_sigma.size(); ++i)
    if (!(albedo_sigma[i] > 0)) return bad("albedo sigma must be positive");
  return true;
}

}  // namespace face_reenact
