// Pose from landmarks (the tracker's recovery initialisation) and the landmark reprojection
// error its loss detection uses. See face_tracker.h.
#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <optional>
#include <unordered_map>

#include "face_reenact/landmarks/evaluation.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/fit_agreement.h"
#include "math_internal.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
using internal::model_vertex;
using internal::project;
namespace {
constexpr double kPi = 3.14159265358979323846;

struct Correspondence {
  Eigen::Vector3d model;   // model frame
  Eigen::Vector2d pixel;   // frame pixels
  double weight = 1;       // confidence
  bool silhouette = false;
  double depth = 0;        // measured depth at the landmark (metres), 0 = none
};

// R = Rz(c) Ry(b) Rx(a) -> (a, b, c), with a in [0, 2 pi) so a frontal face has a = pi.
Eigen::Vector3d euler_from_rotation(const Eigen::Matrix3d& r) {
  const double b = std::asin(std::clamp(-r(2, 0), -1.0, 1.0));
  double a = std::atan2(r(2, 1), r(2, 2));
  const double c = std::atan2(r(1, 0), r(0, 0));
  if (a < 0) a += 2 * kPi;
  return {a, b, c};
}

// Median of the valid depths in a (2r+1)^2 window around a pixel; 0 when none.
double window_depth(const InputFrame& frame, const Eigen::Vector2d& p, int radius) {
  if (!(std::abs(p.x()) < 1e6 && std::abs(p.y()) < 1e6)) return 0;  // far outside any image
  const int ci = static_cast<int>(std::lround(p.x())), cj = static_cast<int>(std::lround(p.y()));
  std::vector<float> values;
  for (int dj = -radius; dj <= radius; ++dj) {
    for (int di = -radius; di <= radius; ++di) {
      if (frame.depth_valid(ci + di, cj + dj)) values.push_back(frame.depth[static_cast<size_t>(cj + dj) * frame.width() + ci + di]);
    }
  }
  return internal::median(std::move(values));
}

// Rigid 3D-3D alignment (no scale) of model points onto camera points, weighted (Umeyama).
bool rigid_align(const std::vector<Eigen::Vector3d>& from, const std::vector<Eigen::Vector3d>& to,
                 const std::vector<double>& w, Eigen::Matrix3d* r, Eigen::Vector3d* t) {
  double wsum = 0;
  Eigen::Vector3d mf = Eigen::Vector3d::Zero(), mt = Eigen::Vector3d::Zero();
  for (size_t k = 0; k < from.size(); ++k) {
    mf += w[k] * from[k];
    mt += w[k] * to[k];
    wsum += w[k];
  }
  if (!(wsum > 0)) return false;
  mf /= wsum;
  mt /= wsum;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (size_t k = 0; k < from.size(); ++k) cov += w[k] * (to[k] - mt) * (from[k] - mf).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) d(2, 2) = -1;
  *r = svd.matrixU() * d * svd.matrixV().transpose();
  *t = mt - *r * mf;
  return r->allFinite() && t->allFinite();
}

// Levenberg-Marquardt on the weighted reprojection error over (rotation increment, t), plus
// the depth of the landmarks that have a measurement (fixes the distance, which the image
// alone ties to the unknown face size).
double refine_pnp(const gpu::PinholeCamera& cam, const std::vector<Correspondence>& cs, int max_iterations,
                  Eigen::Matrix3d* r, Eigen::Vector3d* t) {
  // A depth offset in pixel-equivalent units (how far the point would move in the image were
  // the offset sideways), so a depth measurement weighs about as much as a landmark.
  const double f = 0.5 * (cam.fx + cam.fy);
  auto depth_scale = [f](const Correspondence& k) { return f / k.depth; };
  auto cost = [&](const Eigen::Matrix3d& rr, const Eigen::Vector3d& tt) {
    double c = 0;
    for (const auto& k : cs) {
      const Eigen::Vector3d x = rr * k.model + tt;
      if (!(x.z() > cam.near_plane)) return std::numeric_limits<double>::infinity();
      c += k.weight * (project(cam, x) - k.pixel).squaredNorm();
      if (k.depth > 0) c += k.weight * std::pow(depth_scale(k) * (x.z() - k.depth), 2);
    }
    return c;
  };
  double current = cost(*r, *t);
  double lambda = 1e-3;
  for (int it = 0; it < max_iterations && std::isfinite(current); ++it) {
    Eigen::Matrix<double, 6, 6> h = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> g = Eigen::Matrix<double, 6, 1>::Zero();
    for (const auto& k : cs) {
      const Eigen::Vector3d rv = *r * k.model;
      const Eigen::Vector3d x = rv + *t;
      const double iz = 1.0 / x.z();
      Eigen::Matrix<double, 2, 3> dp;
      dp << cam.fx * iz, 0, -cam.fx * x.x() * iz * iz, 0, cam.fy * iz, -cam.fy * x.y() * iz * iz;
      Eigen::Matrix<double, 3, 6> dx;
      // X = exp([w]) R v + t: dX/dw = -[R v]_x, dX/dt = I.
      Eigen::Matrix3d skew;
      skew << 0, -rv.z(), rv.y(), rv.z(), 0, -rv.x(), -rv.y(), rv.x(), 0;
      dx.leftCols<3>() = -skew;
      dx.rightCols<3>() = Eigen::Matrix3d::Identity();
      const Eigen::Matrix<double, 2, 6> j = dp * dx;
      const Eigen::Vector2d res = project(cam, x) - k.pixel;
      h += k.weight * j.transpose() * j;
      g += k.weight * j.transpose() * res;
      if (k.depth > 0) {
        const Eigen::Matrix<double, 1, 6> jd = depth_scale(k) * dx.row(2);
        h += k.weight * jd.transpose() * jd;
        g += k.weight * jd.transpose() * (depth_scale(k) * (x.z() - k.depth));
      }
    }
    bool improved = false;
    for (int tries = 0; tries < 8 && !improved; ++tries) {
      Eigen::Matrix<double, 6, 6> a = h;
      a.diagonal() += lambda * (h.diagonal().array() + 1e-9).matrix();
      const Eigen::Matrix<double, 6, 1> step = a.ldlt().solve(-g);
      if (!step.allFinite()) break;
      const Eigen::Vector3d w = step.head<3>();
      const double angle = w.norm();
      const Eigen::Matrix3d dr =
          angle > 0 ? Eigen::AngleAxisd(angle, w / angle).toRotationMatrix() : Eigen::Matrix3d::Identity();
      const Eigen::Matrix3d r_try = dr * *r;
      const Eigen::Vector3d t_try = *t + step.tail<3>();
      const double c = cost(r_try, t_try);
      if (c < current) {
        const double gain = current - c;
        *r = r_try;
        *t = t_try;
        current = c;
        lambda = std::max(lambda * 0.3, 1e-7);
        improved = true;
        if (gain < 1e-10 * (1 + current)) return current;
      } else {
        lambda *= 10;
      }
    }
    if (!improved) break;
  }
  return current;
}

}  // namespace

bool PoseInitOptions::IsValid(std::string* why) const {
  if (min_landmarks < 3 || min_landmarks > 68) return fail_why(why, "pose init: min_landmarks must be 3..68");
  if (!(min_confidence >= 0.f) || !(min_confidence <= 1.f)) return fail_why(why, "pose init: min_confidence must be in [0, 1]");
  if (max_iterations < 1 || max_iterations > 1000) return fail_why(why, "pose init: max_iterations must be 1..1000");
  if (!(default_distance_m > 0.05f) || !(default_distance_m < 50.f)) {
    return fail_why(why, "pose init: default_distance_m must be in (0.05, 50) m");
  }
  return true;
}

double LandmarkReprojectionError(const TrackerModel& model, const InputFrame& frame, const gpu::FaceParameters& params,
                                 float min_confidence, bool inner_only, int* used) {
  std::unordered_map<int, int> vertex_of;
  for (const auto& l : model.landmarks) {
    if (inner_only && !(l.flags & kLandmarkInner)) continue;
    vertex_of[l.ibug_index] = l.vertex;
  }
  const Eigen::Matrix3d r = internal::rotation_with_derivatives(params.euler.cast<double>()).r;
  const Eigen::Vector3d t = params.translation.cast<double>();
  double sum = 0;
  int count = 0;
  for (const auto& in : frame.landmarks) {
    if (!(in.confidence > min_confidence)) continue;
    const auto it = vertex_of.find(in.ibug_index);
    if (it == vertex_of.end()) continue;
    const Eigen::Vector3d x = r * model_vertex(model, params, it->second) + t;
    ++count;
    if (!(x.z() > frame.camera.near_plane)) {
      sum += frame.camera.width;  // behind the camera: as far off as it gets
      continue;
    }
    sum += (project(frame.camera, x) - in.position.cast<double>()).norm();
  }
  if (used) *used = count;
  if (count == 0) return -1;
  return sum / count * 640.0 / frame.camera.width;
}

PoseInitResult InitializePoseFromLandmarks(const TrackerModel& model, const InputFrame& frame,
                                           const gpu::FaceParameters& shape, const PoseInitOptions& options) {
  PoseInitResult result;
  std::string why;
  if (!options.IsValid(&why)) {
    result.message = why;
    return result;
  }
  std::unordered_map<int, const TrackerLandmark*> by_index;
  for (const auto& l : model.landmarks) {
    if (options.inner_landmarks_only && !(l.flags & kLandmarkInner)) continue;
    by_index[l.ibug_index] = &l;
  }
  std::vector<Correspondence> cs;
  for (const auto& in : frame.landmarks) {
    if (!(in.confidence > options.min_confidence)) continue;
    const auto it = by_index.find(in.ibug_index);
    if (it == by_index.end()) continue;
    Correspondence c;
    c.model = model_vertex(model, shape, it->second->vertex);
    c.pixel = in.position.cast<double>();
    c.weight = in.confidence;
    c.silhouette = (it->second->flags & kLandmarkSilhouette) != 0;
    cs.push_back(c);
  }
  result.landmarks_used = static_cast<int>(cs.size());
  if (static_cast<int>(cs.size()) < options.min_landmarks) {
    result.message = "pose init: " + std::to_string(cs.size()) + " usable landmarks, " +
                     std::to_string(options.min_landmarks) + " needed";
    return result;
  }
  const gpu::PinholeCamera& cam = frame.camera;

  // Candidate starts: a 3D-3D alignment to the back-projected landmarks when the frame has
  // depth at enough of them (silhouette points excluded: their depth often hits the
  // background), and frontal poses turned by -40..40 degrees of yaw at the distance that
  // matches the landmarks' image spread.
  std::vector<std::pair<Eigen::Matrix3d, Eigen::Vector3d>> starts;
  if (frame.has_depth() && options.use_depth) {
    std::vector<Eigen::Vector3d> from, to;
    std::vector<double> w;
    for (auto& c : cs) {
      if (c.silhouette) continue;
      const double z = window_depth(frame, c.pixel, 1);
      if (!(z > 0)) continue;
      c.depth = z;
      from.push_back(c.model);
      to.push_back({(c.pixel.x() - cam.cx) * z / cam.fx, (c.pixel.y() - cam.cy) * z / cam.fy, z});
      w.push_back(c.weight);
    }
    Eigen::Matrix3d r;
    Eigen::Vector3d t;
    if (static_cast<int>(from.size()) >= std::max(options.min_landmarks, 4) && rigid_align(from, to, w, &r, &t)) {
      // One reweighting pass: points off by more than 3x the median (a landmark on a depth
      // edge, a wrong detection) are dropped.
      std::vector<double> err(from.size());
      for (size_t k = 0; k < from.size(); ++k) err[k] = (r * from[k] + t - to[k]).norm();
      const double limit = std::max(3 * internal::median(err), 0.005);
      for (size_t k = 0; k < from.size(); ++k) {
        if (err[k] > limit) w[k] = 0;
      }
      Eigen::Matrix3d r2;
      Eigen::Vector3d t2;
      if (rigid_align(from, to, w, &r2, &t2)) {
        r = r2;
        t = t2;
      }
      starts.emplace_back(r, t);
      result.used_depth = true;
    }
  }
  {
    Eigen::Vector2d pc = Eigen::Vector2d::Zero();
    Eigen::Vector3d mc = Eigen::Vector3d::Zero();
    double wsum = 0;
    for (const auto& c : cs) {
      pc += c.weight * c.pixel;
      mc += c.weight * c.model;
      wsum += c.weight;
    }
    pc /= wsum;
    mc /= wsum;
    double spread_px = 0, spread_m = 0;
    for (const auto& c : cs) {
      spread_px += c.weight * (c.pixel - pc).norm();
      spread_m += c.weight * (c.model - mc).head<2>().norm();
    }
    double z = options.default_distance_m;
    if (spread_px > 1e-6 && spread_m > 1e-9) z = 0.5 * (cam.fx + cam.fy) * spread_m / spread_px;
    z = std::clamp(z, static_cast<double>(cam.near_plane) * 2 + 0.05, static_cast<double>(cam.far_plane) * 0.5);
    const Eigen::Vector3d centre((pc.x() - cam.cx) * z / cam.fx, (pc.y() - cam.cy) * z / cam.fy, z);
    for (double yaw_deg : {0.0, -25.0, 25.0, -45.0, 45.0}) {
      const Eigen::Matrix3d r = internal::rotation_with_derivatives(Eigen::Vector3d(kPi, yaw_deg * kPi / 180.0, 0.0)).r;
      starts.emplace_back(r, centre - r * mc);
    }
  }

  double best = std::numeric_limits<double>::infinity();
  Eigen::Matrix3d best_r = Eigen::Matrix3d::Identity();
  Eigen::Vector3d best_t = Eigen::Vector3d::Zero();
  for (auto [r, t] : starts) {
    const double c = refine_pnp(cam, cs, options.max_iterations, &r, &t);
    if (c < best) {
      best = c;
      best_r = r;
      best_t = t;
    }
  }
  if (!std::isfinite(best)) {
    result.message = "pose init: the landmark fit put the face behind the camera from every start";
    return result;
  }
  double wsum = 0, err = 0;
  for (const auto& c : cs) {
    const Eigen::Vector3d x = best_r * c.model + best_t;
    err += (project(cam, x) - c.pixel).norm();
    wsum += 1;
  }
  result.mean_error_px = err / wsum;
  result.euler = euler_from_rotation(best_r).cast<float>();
  result.translation = best_t.cast<float>();
  if (!result.euler.allFinite() || !result.translation.allFinite()) {
    result.message = "pose init: the landmark fit did not converge (non-finite pose)";
    return result;
  }
  result.ok = true;
  char buf[160];
  std::snprintf(buf, sizeof(buf), "pose from %d landmarks%s, reprojection error %.1f px", result.landmarks_used,
                result.used_depth ? " (3D start from depth)" : "", result.mean_error_px);
  result.message = buf;
  return result;
}

bool FitAgreementOptions::IsValid(std::string* why) const {
  auto off_or_positive = [](double v) { return std::isfinite(v) && v >= 0; };
  if (!off_or_positive(max_pose_disagreement_deg) || max_pose_disagreement_deg > 180)
    return fail_why(why, "fit agreement: max_pose_disagreement_deg must be in [0, 180] (0: off)");
  if (!off_or_positive(max_landmark_nme) || max_landmark_nme > 10)
    return fail_why(why, "fit agreement: max_landmark_nme must be in [0, 10] (0: off)");
  if (!off_or_positive(max_rotation_speed_deg_s) || max_rotation_speed_deg_s > 1e5)
    return fail_why(why, "fit agreement: max_rotation_speed_deg_s must be in [0, 100000] (0: off)");
  if (!(min_landmark_confidence >= 0.f && min_landmark_confidence < 1.f))
    return fail_why(why, "fit agreement: min_landmark_confidence must be in [0, 1)");
  if (!off_or_positive(pose_tie_nme) || pose_tie_nme > 10) return fail_why(why, "fit agreement: pose_tie_nme must be in [0, 10]");
  return true;
}

double RotationAngleDeg(const Eigen::Vector3f& euler_a, const Eigen::Vector3f& euler_b) {
  const Eigen::Matrix3d a = internal::rotation_with_derivatives(euler_a.cast<double>()).r;
  const Eigen::Matrix3d b = internal::rotation_with_derivatives(euler_b.cast<double>()).r;
  const double c = std::clamp(((a.transpose() * b).trace() - 1.0) / 2.0, -1.0, 1.0);
  return std::acos(c) * 180.0 / kPi;
}

ProjectedLandmarks ProjectModelLandmarks(const TrackerModel& model, const gpu::FaceParameters& params,
                                         const gpu::PinholeCamera& camera, const std::vector<TrackerLandmark>* landmarks) {
  ProjectedLandmarks out;
  const Eigen::Matrix3d r = internal::rotation_with_derivatives(params.euler.cast<double>()).r;
  const Eigen::Vector3d t = params.translation.cast<double>();
  for (const auto& l : landmarks ? *landmarks : model.landmarks) {
    if (l.ibug_index < 0 || l.ibug_index >= landmarks::kNumLandmarks) continue;
    const size_t k = static_cast<size_t>(l.ibug_index);
    const Eigen::Vector3d x = r * model_vertex(model, params, l.vertex) + t;
    out.points[k] = x.z() > camera.near_plane ? project(camera, x).cast<float>() : Eigen::Vector2f(1e9f, 1e9f);
    out.bound[k] = true;
  }
  return out;
}

std::vector<TrackerLandmark> ContourLandmarks(const TrackerModel& model, const gpu::FaceParameters& params,
                                              const gpu::PinholeCamera& camera) {
  std::vector<TrackerLandmark> out = model.landmarks;
  std::array<int, 68> bound;
  bound.fill(-1);
  for (const auto& l : model.landmarks) {
    if (l.ibug_index >= 0 && l.ibug_index < 68) bound[static_cast<size_t>(l.ibug_index)] = l.vertex;
  }
  for (int k : {0, 8, 16, 27, 36, 45, 48, 54}) {
    if (bound[static_cast<size_t>(k)] < 0) return out;
  }
  if (!params.euler.allFinite() || !params.translation.allFinite()) return out;
  const auto& mean = model.render.mean_shape;
  auto at = [&](int v) -> Eigen::Vector3d { return mean.segment<3>(3 * v).cast<double>(); };
  // The face's frontal plane on the mean face: up from the chin to the nasal bridge, the side
  // axis between the jaw line's two ends, and its middle between the eyes and the mouth.
  const Eigen::Vector3d up = (at(bound[27]) - at(bound[8])).normalized();
  Eigen::Vector3d side = at(bound[0]) - at(bound[16]);
  side = (side - side.dot(up) * up).normalized();
  Eigen::Vector3d middle = Eigen::Vector3d::Zero();
  for (int k : {36, 45, 48, 54}) middle += 0.25 * at(bound[static_cast<size_t>(k)]);
  auto plane_angle = [&](const Eigen::Vector3d& q) {
    const Eigen::Vector3d d = q - middle;
    return std::atan2(d.dot(up), d.dot(side));
  };
  const Eigen::Matrix3d r = internal::rotation_with_derivatives(params.euler.cast<double>()).r;
  const Eigen::Vector3d t = params.translation.cast<double>();
  auto shown_at = [&](const Eigen::Vector3d& model_point) -> std::optional<Eigen::Vector2d> {
    const Eigen::Vector3d x = r * model_point + t;
    if (!(x.z() > camera.near_plane)) return std::nullopt;
    return project(camera, x);
  };
  // The posed face's middle, and its face part's vertices as the image shows them.
  Eigen::Vector3d posed_middle = Eigen::Vector3d::Zero();
  for (int k : {36, 45, 48, 54}) posed_middle += 0.25 * internal::model_vertex(model, params, bound[static_cast<size_t>(k)]);
  const std::optional<Eigen::Vector2d> middle_shown = shown_at(posed_middle);
  if (!middle_shown) return out;
  std::vector<int> face;
  std::vector<Eigen::Vector2d> shown;
  std::vector<double> angle;
  for (int v = 0; v < model.num_vertices(); ++v) {
    if (model.render.vertex_part[static_cast<size_t>(v)] != static_cast<uint8_t>(FacePart::Face)) continue;
    const std::optional<Eigen::Vector2d> x = shown_at(internal::model_vertex(model, params, v));
    if (!x) continue;
    face.push_back(v);
    shown.push_back(*x);
    angle.push_back(plane_angle(at(v)));
  }
  // Each jaw point: in the face's frontal plane, the wedge of directions from the middle through
  // its bound vertex; among the face's vertices in that wedge, the one that projects farthest
  // out along that direction in the image. Along the sides the direction is the side axis, and
  // the point slides over the cheek as it turns away; near the chin it points down and out,
  // where a band at the bound vertex's height crossed the chin's underside (points 6 and 10 were
  // 0.15-0.17 eye distances off the annotation that way, 0.04-0.06 now).
  for (auto& l : out) {
    if (!(l.flags & kLandmarkSilhouette)) continue;
    const Eigen::Vector3d d = at(l.vertex) - middle;
    const double phi = plane_angle(at(l.vertex));
    const Eigen::Vector3d outward_model = (d.dot(side) * side + d.dot(up) * up).normalized();
    const std::optional<Eigen::Vector2d> towards = shown_at(posed_middle + 0.05 * outward_model);
    if (!towards) continue;
    const Eigen::Vector2d direction = (*towards - *middle_shown).normalized();
    if (!direction.allFinite()) continue;
    double best = -std::numeric_limits<double>::infinity();
    int best_vertex = l.vertex;  // the bound vertex always competes
    if (auto b = shown_at(internal::model_vertex(model, params, l.vertex))) best = (*b - *middle_shown).dot(direction);
    for (size_t i = 0; i < face.size(); ++i) {
      double dphi = std::abs(angle[i] - phi);
      dphi = std::min(dphi, 2 * M_PI - dphi);
      if (dphi > kContourWedgeRad) continue;
      const double outward = (shown[i] - *middle_shown).dot(direction);
      if (outward > best) {
        best = outward;
        best_vertex = face[i];
      }
    }
    l.vertex = best_vertex;
  }
  return out;
}

FitAgreement MeasureFitAgreement(const TrackerModel& model, const InputFrame& frame, const gpu::FaceParameters& params,
                                 const FitAgreementOptions& options, const gpu::FaceParameters* previous,
                                 double seconds_since_previous) {
  FitAgreement out;
  if (!options.IsValid(&out.failure)) return out;
  if (!params.euler.allFinite() || !params.translation.allFinite()) {
    out.failure = "the fitted pose is not finite";
    return out;
  }
  char buf[200];
  // The inner 51 points (brows, nose, eyes, mouth) of the fit against the detector's, in the
  // normalisation of `landmarks --eval` (landmarks::nme_outer_eye), overall and per part.
  landmarks::Shape68 fitted{}, detected{};
  std::array<bool, 68> seen{};
  for (const auto& in : frame.landmarks) {
    if (in.ibug_index >= 0 && in.ibug_index < 68 && in.confidence > options.min_landmark_confidence &&
        in.position.allFinite()) {
      detected[static_cast<size_t>(in.ibug_index)] = in.position;
      seen[static_cast<size_t>(in.ibug_index)] = true;
    }
  }
  if (seen[36] && seen[45]) {
    const double iod = (detected[36] - detected[45]).cast<double>().norm();
    out.eye_distance_px = iod;
    const ProjectedLandmarks projected = ProjectModelLandmarks(model, params, frame.camera);
    fitted = projected.points;
    std::array<bool, 68> inner{};
    std::array<std::array<bool, 68>, 4> part{};  // brows 17-26, nose 27-35, eyes 36-47, mouth 48-67
    for (int i = 17; i < 68; ++i) {
      const size_t k = static_cast<size_t>(i);
      if (!projected.bound[k] || !seen[k]) continue;
      inner[k] = true;
      part[i < 27 ? 0 : i < 36 ? 1 : i < 48 ? 2 : 3][k] = true;
      ++out.landmarks_used;
    }
    // NaN where no point was compared (nme_outer_eye gives infinity).
    auto nme = [&](const std::array<bool, 68>& use) {
      const double v = landmarks::nme_outer_eye(fitted, detected, use);
      return std::isfinite(v) ? v : FitAgreement::kNaN;
    };
    if (out.landmarks_used > 0 && iod > 1.0) {
      out.landmark_nme = nme(inner);
      out.nme_brows = nme(part[0]);
      out.nme_nose = nme(part[1]);
      out.nme_eyes = nme(part[2]);
      out.nme_mouth = nme(part[3]);
    }
  }
  // The head pose the landmarks give by themselves, with this fit's shape.
  PoseInitOptions po;
  po.min_confidence = options.min_landmark_confidence;
  po.inner_landmarks_only = true;  // the jaw line's points slide along the silhouette
  // The landmarks alone: depth sampled at a landmark's pixel is the surface seen there (a lid, a
  // lip, the background past a turned cheek), not the landmark vertex's, and turned a perfect fit
  // of a synthetic frame 3 degrees away.
  po.use_depth = false;
  po.default_distance_m = std::max(0.1f, std::min(params.translation.z(), 20.f));
  const PoseInitResult pnp = InitializePoseFromLandmarks(model, frame, params, po);
  if (pnp.ok) {
    out.pose_disagreement_deg = RotationAngleDeg(params.euler, pnp.euler);
    out.landmark_pose_error_px = pnp.mean_error_px;
    // The fit on the same points, in the same unit (the frame's pixels).
    const double fit_error = LandmarkReprojectionError(model, frame, params, options.min_landmark_confidence,
                                                       /*inner_only=*/true);
    if (fit_error >= 0) out.fit_error_px = fit_error * frame.camera.width / 640.0;
  }
  if (previous && previous->euler.allFinite() && seconds_since_previous > 0) {
    out.rotation_change_deg = RotationAngleDeg(params.euler, previous->euler);
    out.rotation_speed_deg_s = out.rotation_change_deg / seconds_since_previous;
  }

  if (options.max_landmark_nme > 0 && out.landmark_nme > options.max_landmark_nme) {
    std::snprintf(buf, sizeof buf, "inner landmarks %.1f%% of the eye distance from the detector's (limit %.1f%%)",
                  100 * out.landmark_nme, 100 * options.max_landmark_nme);
    out.landmark_warning = buf;
  }
  if (options.max_pose_disagreement_deg > 0 && out.pose_disagreement_deg > options.max_pose_disagreement_deg) {
    std::snprintf(buf, sizeof buf, "head pose %.1f degrees from the landmarks' (limit %.0f)", out.pose_disagreement_deg,
                  options.max_pose_disagreement_deg);
    out.failure = buf;
  } else if (options.max_rotation_speed_deg_s > 0 && out.rotation_speed_deg_s > options.max_rotation_speed_deg_s) {
    std::snprintf(buf, sizeof buf, "head turned %.1f degrees in %.0f ms (limit %.0f degrees/s)", out.rotation_change_deg,
                  1000 * seconds_since_previous, options.max_rotation_speed_deg_s);
    out.failure = buf;
  }
  return out;
}

}  // namespace face_reenact::tracker
