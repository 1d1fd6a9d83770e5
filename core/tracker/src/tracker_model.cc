#include "face_reenact/tracker/tracker_model.h"

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"

namespace face_reenact::tracker {
bool TrackerModel::IsValid(std::string* why) const {
  if (!render.IsValid(why)) return false;
  if (identity_sigma.size() != num_identity()) return fail_why(why, "tracker model: one identity sigma per identity column needed");
  if (albedo_sigma.size() != num_albedo()) return fail_why(why, "tracker model: one albedo sigma per albedo column needed");
  if ((identity_sigma.size() > 0 && !(identity_sigma.array() > 0.f).all()) ||
      (albedo_sigma.size() > 0 && !(albedo_sigma.array() > 0.f).all()) || !(expression_sigma > 0.f)) {
    return fail_why(why, "tracker model: prior standard deviations must be positive");
  }
  for (const auto& l : landmarks) {
    if (l.vertex < 0 || l.vertex >= num_vertices()) return fail_why(why, "tracker model: landmark vertex out of range");
    if (l.ibug_index < 0 || l.ibug_index > 67) return fail_why(why, "tracker model: landmark index outside 0..67");
  }
  return true;
}

TrackerModel TrackerModel::FromFaceModel(const FaceModel& model) {
  TrackerModel t;
  t.render = gpu::RenderModel::FromFaceModel(model);
  t.identity_sigma = model.identity_sigma;
  t.albedo_sigma = model.albedo_sigma;
  t.expression_sigma = 1.0f;  // face_model.h: blendshape weights in [0, 1], sigma_exp = 1
  for (const auto& l : model.landmarks) t.landmarks.push_back({l.ibug_index, l.vertex, l.flags});
  std::string why;
  if (!t.IsValid(&why)) throw Error("face model cannot be tracked: " + why);
  return t;
}

}  // namespace face_reenact::tracker
