#include "face_reenact/tracker/brow_reader.h"

#include <algorithm>
#include <cmath>
#include <complex>
#include <optional>
#include <vector>

#include "face_reenact/model/face_model.h"
#include "math_internal.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {

bool BrowReaderOptions::IsValid(std::string* why) const {
  auto fail = [&](const char* m) {
    if (why) *why = std::string("brow reader options: ") + m;
    return false;
  };
  if (history_frames < 1 || history_frames > 100000) return fail("history_frames must be 1..100000");
  if (min_history < 1 || min_history > history_frames) return fail("min_history must be 1..history_frames");
  if (!(dead_zone >= 0.0 && dead_zone < 1.0)) return fail("dead_zone must be in [0, 1)");
  if (!(min_confidence >= 0.f && min_confidence <= 1.f)) return fail("min_confidence must be in [0, 1]");
  if (median_frames < 1 || median_frames > 31) return fail("median_frames must be 1..31");
  return true;
}

const std::array<const char*, kNumBrowBlendshapes>& brow_blendshape_names() {
  static const std::array<const char*, kNumBrowBlendshapes> names = {"browInnerUp", "browOuterUpLeft", "browOuterUpRight",
                                                                     "browDownLeft", "browDownRight"};
  return names;
}

namespace {

// The reference points the brows are measured against: the eye corners (a blink does not move
// them) and the nasal bridge (27-30: no expression moves it), which a look aside moves less than
// the corners alone.
constexpr std::array<int, 8> kReference = {36, 39, 42, 45, 27, 28, 29, 30};

// The complex scale-rotation a and the centroids of the 2D similarity p -> to_mean + a (p -
// from_mean) that brings `from` onto `to` in least squares; nullopt when `from` has no extent.
struct Similarity {
  Eigen::Vector2d from_mean, to_mean;
  std::complex<double> a;
  Eigen::Vector2d Apply(const Eigen::Vector2d& p) const { return to_mean + Rotate(p - from_mean); }
  Eigen::Vector2d Rotate(const Eigen::Vector2d& v) const {
    const std::complex<double> z = a * std::complex<double>(v.x(), v.y());
    return {z.real(), z.imag()};
  }
};
template <size_t N>
std::optional<Similarity> FitSimilarity(const std::array<Eigen::Vector2d, N>& from, const std::array<Eigen::Vector2d, N>& to) {
  Similarity s;
  s.from_mean.setZero();
  s.to_mean.setZero();
  for (size_t i = 0; i < N; ++i) {
    s.from_mean += from[i] / double(N);
    s.to_mean += to[i] / double(N);
  }
  std::complex<double> num = 0;
  double den = 0;
  for (size_t i = 0; i < N; ++i) {
    const Eigen::Vector2d f = from[i] - s.from_mean, t = to[i] - s.to_mean;
    num += std::conj(std::complex<double>(f.x(), f.y())) * std::complex<double>(t.x(), t.y());
    den += f.squaredNorm();
  }
  if (!(den > 1e-12) || !std::isfinite(den)) return std::nullopt;
  s.a = num / den;
  return s;
}

}  // namespace

BrowReader::BrowReader(const TrackerModel& model, const BrowReaderOptions& options) : model_(&model), options_(options) {
  brow_vertex_.fill(-1);
  reference_vertex_.fill(-1);
  const int n = model.num_vertices();
  for (const TrackerLandmark& l : model.landmarks) {
    if (l.vertex < 0 || l.vertex >= n) continue;
    if (l.ibug_index >= 17 && l.ibug_index <= 26) brow_vertex_[size_t(l.ibug_index - 17)] = l.vertex;
    for (size_t c = 0; c < kReference.size(); ++c)
      if (l.ibug_index == kReference[c]) reference_vertex_[c] = l.vertex;
  }
  usable_ = std::none_of(brow_vertex_.begin(), brow_vertex_.end(), [](int v) { return v < 0; }) &&
            std::none_of(reference_vertex_.begin(), reference_vertex_.end(), [](int v) { return v < 0; });
  for (int b = 0; b < kNumBrowBlendshapes; ++b) {
    blendshape_[size_t(b)] = arkit_blendshape_index(brow_blendshape_names()[size_t(b)]);
    if (blendshape_[size_t(b)] < 0 || blendshape_[size_t(b)] >= model.num_expression()) usable_ = false;
  }
}

void BrowReader::Write(const BrowReading& reading, Eigen::VectorXf* delta) const {
  for (int b = 0; b < kNumBrowBlendshapes; ++b) {
    const int k = blendshape_[size_t(b)];
    if (k >= 0 && k < delta->size()) (*delta)[k] = reading.weight[size_t(b)];
  }
}

void BrowReader::ClearBrows(Eigen::VectorXf* delta) const {
  for (int k : blendshape_)
    if (k >= 0 && k < delta->size()) (*delta)[k] = 0.f;
}

BrowReading BrowReader::Read(const InputFrame& frame, const gpu::FaceParameters& params, const gpu::PinholeCamera& camera) {
  BrowReading r;
  if (!options_.enabled) {
    r.message = "off";
    return r;
  }
  if (!usable_) {
    r.message = "the model has no brow points or brow blendshapes";
    return r;
  }
  // The detector's points.
  std::array<Eigen::Vector2d, kPoints> brow;
  std::array<Eigen::Vector2d, kReference.size()> reference;
  int found = 0;
  for (const InputLandmark& l : frame.landmarks) {
    if (!(l.confidence >= options_.min_confidence) || !l.position.allFinite()) continue;
    if (l.ibug_index >= 17 && l.ibug_index <= 26) {
      brow[size_t(l.ibug_index - 17)] = l.position.cast<double>();
      found |= 1 << (l.ibug_index - 17);
    }
    for (size_t c = 0; c < kReference.size(); ++c) {
      if (l.ibug_index != kReference[c]) continue;
      reference[c] = l.position.cast<double>();
      found |= 1 << (kPoints + int(c));
    }
  }
  if (found != (1 << (kPoints + int(kReference.size()))) - 1) {
    r.message = "no confident brow, eye-corner and nasal-bridge points";
    return r;
  }
  // The face's frame in the image: x along the eye line towards the person's left eye (each eye's
  // middle is its corners' midpoint), y up the face (the image's y runs down), unit the eye distance.
  const Eigen::Vector2d right_eye = 0.5 * (reference[0] + reference[1]), left_eye = 0.5 * (reference[2] + reference[3]);
  const double eye_distance = (left_eye - right_eye).norm();
  if (!(eye_distance > 1e-6) || !std::isfinite(eye_distance)) {
    r.message = "the eye corners coincide";
    return r;
  }
  const Eigen::Vector2d x_axis = (left_eye - right_eye) / eye_distance, y_axis(x_axis.y(), -x_axis.x());
  const auto in_face_frame = [&](const Eigen::Vector2d& v) -> Eigen::Vector2d {
    return Eigen::Vector2d(v.dot(x_axis), v.dot(y_axis)) / eye_distance;
  };

  // The model's points under the fit with the brows at rest, brought onto the detector's reference
  // points by a 2D similarity (which takes out the fitted face's scale and distance).
  gpu::FaceParameters rest = params;
  ClearBrows(&rest.delta);
  const Eigen::Matrix3d rot = internal::rotation_with_derivatives(params.euler.cast<double>()).r;
  const Eigen::Vector3d t = params.translation.cast<double>();
  std::array<Eigen::Vector3d, kPoints> brow3;
  std::array<Eigen::Vector2d, kPoints> brow2;
  std::array<Eigen::Vector2d, kReference.size()> reference2;
  for (int k = 0; k < kPoints; ++k) {
    brow3[size_t(k)] = rot * internal::model_vertex(*model_, rest, brow_vertex_[size_t(k)]) + t;
    if (!(brow3[size_t(k)].z() > camera.near_plane)) {
      r.message = "the fit's brows are not in front of the camera";
      return r;
    }
    brow2[size_t(k)] = internal::project(camera, brow3[size_t(k)]);
  }
  for (size_t c = 0; c < reference2.size(); ++c) {
    const Eigen::Vector3d x = rot * internal::model_vertex(*model_, rest, reference_vertex_[c]) + t;
    if (!(x.z() > camera.near_plane)) {
      r.message = "the fit's eyes are not in front of the camera";
      return r;
    }
    reference2[c] = internal::project(camera, x);
  }
  const std::optional<Similarity> align = FitSimilarity(reference2, reference);
  if (!align) {
    r.message = "the fit's reference points coincide";
    return r;
  }
  // What the detector's brows do beyond the model's rest brows, and each blendshape's motion of
  // the points per unit weight (the projection is not linear: a difference over half the range).
  Offsets beyond;
  for (int k = 0; k < kPoints; ++k) beyond.segment<2>(2 * k) = in_face_frame(brow[size_t(k)] - align->Apply(brow2[size_t(k)]));
  constexpr double kStep = 0.5;
  Eigen::Matrix<double, 2 * kPoints, kNumBrowBlendshapes> motion;
  const gpu::RenderModel& rm = model_->render;
  for (int b = 0; b < kNumBrowBlendshapes; ++b) {
    const int e = blendshape_[size_t(b)];
    for (int k = 0; k < kPoints; ++k) {
      const Eigen::Vector3d moved =
          brow3[size_t(k)] + kStep * (rot * rm.expression_basis.block<3, 1>(3 * brow_vertex_[size_t(k)], e).cast<double>());
      if (!(moved.z() > camera.near_plane)) {
        r.message = "the fit's brows are not in front of the camera";
        return r;
      }
      motion.block<2, 1>(2 * k, b) = in_face_frame(align->Rotate(internal::project(camera, moved) - brow2[size_t(k)])) / kStep;
    }
  }

  // The actor's offset: the median of what the points did beyond the model's rest brows.
  history_.push_back(beyond);
  while (static_cast<int>(history_.size()) > options_.history_frames) history_.pop_front();
  if (static_cast<int>(history_.size()) < options_.min_history) {
    r.message = "learning the actor's brows";
    return r;
  }
  Offsets offset;
  std::vector<double> column(history_.size());
  for (Eigen::Index i = 0; i < offset.size(); ++i) {
    for (size_t f = 0; f < history_.size(); ++f) column[f] = history_[f][i];
    offset[i] = internal::median(column);
  }
  const Offsets y = beyond - offset;

  // Bounded least squares (each weight in [0, 1]) by projected coordinate descent: five unknowns,
  // a tiny ridge keeps near-parallel motions (browInnerUp against browDown at the inner ends) apart.
  Eigen::Matrix<double, kNumBrowBlendshapes, kNumBrowBlendshapes> g = motion.transpose() * motion;
  const double ridge = 1e-6 * std::max(g.trace(), 1e-12);
  g.diagonal().array() += ridge;
  const Eigen::Matrix<double, kNumBrowBlendshapes, 1> h = motion.transpose() * y;
  Eigen::Matrix<double, kNumBrowBlendshapes, 1> w = Eigen::Matrix<double, kNumBrowBlendshapes, 1>::Zero();
  for (int sweep = 0; sweep < 200; ++sweep) {
    double change = 0;
    for (int b = 0; b < kNumBrowBlendshapes; ++b) {
      const double rest_of = g.row(b).dot(w) - g(b, b) * w[b];
      const double next = std::clamp((h[b] - rest_of) / g(b, b), 0.0, 1.0);
      change = std::max(change, std::abs(next - w[b]));
      w[b] = next;
    }
    if (change < 1e-7) break;
  }
  r.residual = std::sqrt((motion * w - y).squaredNorm() / double(y.size()));
  std::array<double, kNumBrowBlendshapes> now{};
  for (int b = 0; b < kNumBrowBlendshapes; ++b) now[size_t(b)] = w[b];
  recent_.push_back(now);
  while (static_cast<int>(recent_.size()) > options_.median_frames) recent_.pop_front();
  std::vector<double> values(recent_.size());
  for (int b = 0; b < kNumBrowBlendshapes; ++b) {
    for (size_t f = 0; f < recent_.size(); ++f) values[f] = recent_[f][size_t(b)];
    const double stretched = (internal::median(values) - options_.dead_zone) / (1.0 - options_.dead_zone);
    r.weight[size_t(b)] = static_cast<float>(std::clamp(stretched, 0.0, 1.0));
  }
  r.ok = true;
  r.message = "read from the brow points";
  return r;
}

}  // namespace face_reenact::tracker
