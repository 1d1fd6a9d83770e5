// Where real faces put the iBUG points on the model (landmark_binding.h).
#include "face_reenact/tracker/landmark_binding.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_map>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/face_model_builder.h"
#include "math_internal.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {

bool BindingSearchOptions::IsValid(std::string* why) const {
  if (points.empty()) return fail_why(why, "binding search: no points to search");
  for (int p : points) {
    if (p < 0 || p > 67) return fail_why(why, "binding search: iBUG index " + std::to_string(p) + " outside 0..67");
  }
  if (!(radius_m > 0.001 && radius_m < 0.1)) return fail_why(why, "binding search: radius must be 1..100 mm");
  return true;
}

LandmarkBindingSearch::LandmarkBindingSearch(const TrackerModel& model, std::vector<int32_t> mirror_vertex,
                                             BindingSearchOptions options)
    : model_(model), mirror_(std::move(mirror_vertex)), options_(std::move(options)) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error(why);
  const int n = model_.num_vertices();
  if (static_cast<int>(mirror_.size()) != n) throw Error("binding search: the mirror map does not match the model");
  std::unordered_map<int, int> bound;
  for (const auto& l : model_.landmarks) bound[l.ibug_index] = l.vertex;
  const auto& mean = model_.render.mean_shape;
  for (int ibug : options_.points) {
    const auto it = bound.find(ibug);
    if (it == bound.end()) throw Error("binding search: the model binds no vertex to iBUG point " + std::to_string(ibug));
    Point p;
    p.ibug = ibug;
    p.current = it->second;
    const bool midline = ibug_mirror_partner(ibug) == ibug;
    const Eigen::Vector3f c = mean.segment<3>(3 * p.current);
    for (int v = 0; v < n; ++v) {
      if (model_.render.vertex_part[static_cast<size_t>(v)] != static_cast<uint8_t>(FacePart::Face)) continue;
      if (midline && mirror_[static_cast<size_t>(v)] != v) continue;
      if ((mean.segment<3>(3 * v) - c).norm() > options_.radius_m) continue;
      p.candidates.push_back(v);
    }
    // The current binding always competes (even outside the face part).
    if (std::find(p.candidates.begin(), p.candidates.end(), p.current) == p.candidates.end()) p.candidates.push_back(p.current);
    p.error_sum.assign(p.candidates.size(), 0.0);
    points_.push_back(std::move(p));
  }
}

bool LandmarkBindingSearch::Add(const gpu::FaceParameters& fit, const gpu::PinholeCamera& camera,
                                const std::vector<InputLandmark>& detected) {
  std::array<const InputLandmark*, 68> by_index{};
  for (const auto& l : detected) {
    if (l.ibug_index >= 0 && l.ibug_index < 68 && l.confidence > options_.min_confidence && l.position.allFinite())
      by_index[static_cast<size_t>(l.ibug_index)] = &l;
  }
  if (!by_index[36] || !by_index[45] || !fit.euler.allFinite() || !fit.translation.allFinite()) return false;
  const double iod = (by_index[36]->position - by_index[45]->position).cast<double>().norm();
  if (!(iod > 1.0)) return false;
  const Eigen::Matrix3d r = internal::rotation_with_derivatives(fit.euler.cast<double>()).r;
  const Eigen::Vector3d t = fit.translation.cast<double>();
  for (Point& p : points_) {
    const InputLandmark* l = by_index[static_cast<size_t>(p.ibug)];
    if (!l) continue;
    const Eigen::Vector2d target = l->position.cast<double>();
    for (size_t c = 0; c < p.candidates.size(); ++c) {
      const Eigen::Vector3d x = r * internal::model_vertex(model_, fit, p.candidates[c]) + t;
      p.error_sum[c] += x.z() > camera.near_plane ? (internal::project(camera, x) - target).norm() / iod : 1.0;
    }
    ++p.frames;
  }
  ++frames_;
  return true;
}

std::vector<LandmarkBindingSearch::Result> LandmarkBindingSearch::Results() const {
  std::unordered_map<int, const Point*> by_ibug;
  for (const Point& p : points_) by_ibug[p.ibug] = &p;
  const auto& mean = model_.render.mean_shape;
  auto mean_error = [](const Point& p, size_t c) { return p.frames > 0 ? p.error_sum[c] / p.frames : 0.0; };
  auto index_of = [](const Point& p, int v) -> int {
    const auto it = std::find(p.candidates.begin(), p.candidates.end(), v);
    return it == p.candidates.end() ? -1 : static_cast<int>(it - p.candidates.begin());
  };
  std::vector<Result> out;
  for (const Point& p : points_) {
    Result r;
    r.ibug_index = p.ibug;
    r.frames = p.frames;
    r.current_vertex = p.current;
    r.current_error = mean_error(p, static_cast<size_t>(index_of(p, p.current)));
    // A mirrored pair scores a vertex and its mirror image together, so the chosen binding stays
    // mirror-consistent (the file's promise); a point searched alone, or a midline point, alone.
    const int partner_ibug = ibug_mirror_partner(p.ibug);
    const auto pit = by_ibug.find(partner_ibug);
    const Point* partner = partner_ibug != p.ibug && pit != by_ibug.end() ? pit->second : nullptr;
    double best = std::numeric_limits<double>::infinity();
    for (size_t c = 0; c < p.candidates.size(); ++c) {
      double score = mean_error(p, c);
      if (partner) {
        const int m = index_of(*partner, mirror_[static_cast<size_t>(p.candidates[c])]);
        if (m < 0) continue;
        score += mean_error(*partner, static_cast<size_t>(m));
      }
      if (score < best) {
        best = score;
        r.best_vertex = p.candidates[c];
        r.best_error = mean_error(p, c);
      }
    }
    if (!std::isfinite(best)) {
      r.best_vertex = p.current;
      r.best_error = r.current_error;
    }
    r.best_moved_mm = 1000.0 * (mean.segment<3>(3 * r.best_vertex) - mean.segment<3>(3 * p.current)).norm();
    out.push_back(r);
  }
  return out;
}

nlohmann::json to_json(const std::vector<LandmarkBindingSearch::Result>& results, const std::vector<int32_t>& base_vertex) {
  nlohmann::json a = nlohmann::json::array();
  auto base = [&](int v) { return v >= 0 && v < static_cast<int>(base_vertex.size()) ? base_vertex[static_cast<size_t>(v)] : -1; };
  for (const auto& r : results) {
    a.push_back({{"ibug", r.ibug_index},
                 {"frames", r.frames},
                 {"current_hm08_vertex", base(r.current_vertex)},
                 {"current_error", r.current_error},
                 {"best_hm08_vertex", base(r.best_vertex)},
                 {"best_error", r.best_error},
                 {"best_moved_mm", r.best_moved_mm}});
  }
  return a;
}

}  // namespace face_reenact::tracker
