#include "face_reenact/tracker/focal_length.h"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "face_reenact/common/parallel.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/tracker/face_tracker.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {

bool FocalLengthOptions::IsValid(std::string* why) const {
  if (!(min_fov_deg >= 5 && min_fov_deg < max_fov_deg && max_fov_deg <= 170))
    return fail_why(why, "focal length search: need 5 <= min_fov_deg < max_fov_deg <= 170");
  if (grid_points < 3) return fail_why(why, "focal length search: grid_points must be >= 3");
  if (refine_iterations < 0 || gauss_newton_iterations < 1) return fail_why(why, "focal length search: bad iteration counts");
  if (threads < 0) return fail_why(why, "focal length search: threads must be >= 0 (0: one per hardware thread)");
  if (identity_components < 0) return fail_why(why, "focal length search: identity_components must be >= 0");
  if (!(w_identity >= 0 && w_landmarks > 0)) return fail_why(why, "focal length search: weights must be w_identity >= 0, w_landmarks > 0");
  if (!(fallback_fov_deg > 1 && fallback_fov_deg < 179)) return fail_why(why, "focal length search: fallback_fov_deg must be in (1, 179)");
  if (!(min_landmark_confidence >= 0) || !(max_landmark_rms_px > 0))
    return fail_why(why, "focal length search: min_landmark_confidence >= 0 and max_landmark_rms_px > 0 needed");
  if (!(confidence_chi2 > 0) || !(max_relative_uncertainty > 0))
    return fail_why(why, "focal length search: confidence_chi2 and max_relative_uncertainty must be > 0");
  return true;
}

gpu::PinholeCamera WithHorizontalFov(const gpu::PinholeCamera& camera, double fov_deg) {
  gpu::PinholeCamera c = camera;
  c.fx = c.fy = static_cast<float>(0.5 * camera.width / std::tan(0.5 * fov_deg * M_PI / 180.0));
  return c;
}

double HorizontalFovDeg(const gpu::PinholeCamera& camera) {
  return 2.0 * std::atan(0.5 * camera.width / camera.fx) * 180.0 / M_PI;
}

namespace {

// One calibration frame's landmarks as the fit uses them.
struct FrameLandmarks {
  InputFrame frame;                   // colour dropped: only the camera and landmarks are read
  std::vector<int> vertices;          // model vertex per point
  std::vector<Eigen::Vector2d> uv;    // observed position, pixels
  std::vector<double> weight;         // confidence / sum of confidences
};

// The points the search fits: the inner points of the eyes and nose with their model vertex,
// except 33, which the model puts on the underside of the nose where detectors see the nose base
// (docs/tracker.md): a bias in exactly the depth the search reads. The jaw line is left out: its
// points slide along the occluding contour, which a fixed vertex does not. The mouth (48-67) is
// left out because it moves with speech and this fit has no expression: renders whose jaw opened
// halfway in every other calibration frame read the end of the range (100 degrees) for lenses of
// 45-85 degrees with the mouth in, 46-90 without it.
FrameLandmarks collect(const TrackerModel& model, const InputFrame& frame, float min_confidence) {
  FrameLandmarks f;
  f.frame.camera = frame.camera;
  f.frame.landmarks = frame.landmarks;
  double sum = 0;
  for (const auto& in : frame.landmarks) {
    if (!(in.confidence > min_confidence) || in.ibug_index == 33 || in.ibug_index >= 48) continue;
    if (!in.position.allFinite()) continue;
    for (const auto& l : model.landmarks) {
      if (l.ibug_index != in.ibug_index || !(l.flags & kLandmarkInner)) continue;
      const int v = LandmarkVertex(in, l.vertex, model.num_vertices());
      if (v < 0) break;
      f.vertices.push_back(v);
      f.uv.push_back(in.position.cast<double>());
      f.weight.push_back(in.confidence);
      sum += in.confidence;
      break;
    }
  }
  for (double& w : f.weight) w /= sum;
  return f;
}

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d s;
  s << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return s;
}

// The landmark fit at one field of view: the energy it ends at and its RMS offset (640-wide px).
struct FitResult {
  double energy = std::numeric_limits<double>::infinity();
  double rms_px = -1;
};

class LandmarkFit {
 public:
  LandmarkFit(const TrackerModel& model, std::vector<FrameLandmarks> frames, const FocalLengthOptions& options)
      : model_(model), frames_(std::move(frames)), options_(options),
        k_(std::min(options.identity_components, model.num_identity())) {}

  // Residuals less unknowns: the degrees of freedom the energy's noise is spread over.
  int DegreesOfFreedom() const {
    int residuals = 0;
    for (const FrameLandmarks& f : frames_) residuals += 2 * static_cast<int>(f.vertices.size());
    return residuals - k_ - 6 * static_cast<int>(frames_.size());
  }

  FitResult Solve(double fov_deg) const {
    const int nf = static_cast<int>(frames_.size());
    std::vector<gpu::PinholeCamera> cams(nf);
    std::vector<Eigen::Matrix3d> rot(nf);
    std::vector<Eigen::Vector3d> trans(nf);
    gpu::FaceParameters shape = gpu::frontal_pose(0.6f);
    shape.alpha = Eigen::VectorXf::Zero(model_.num_identity());
    shape.delta = Eigen::VectorXf::Zero(model_.num_expression());
    PoseInitOptions po;
    po.use_depth = false;
    po.min_confidence = options_.min_landmark_confidence;
    for (int f = 0; f < nf; ++f) {
      cams[f] = WithHorizontalFov(frames_[f].frame.camera, fov_deg);
      InputFrame view = frames_[f].frame;
      view.camera = cams[f];
      const PoseInitResult pose = InitializePoseFromLandmarks(model_, view, shape, po);
      if (!pose.ok) return {};
      rot[f] = gpu::rotation_from_euler(pose.euler).cast<double>();
      trans[f] = pose.translation.cast<double>();
    }
    Eigen::VectorXd alpha = Eigen::VectorXd::Zero(k_);
    double lambda = 1e-3;
    double energy = Energy(cams, rot, trans, alpha, nullptr);
    const int n = k_ + 6 * nf;
    for (int it = 0; it < options_.gauss_newton_iterations; ++it) {
      Eigen::MatrixXd jtj = Eigen::MatrixXd::Zero(n, n);
      Eigen::VectorXd jtr = Eigen::VectorXd::Zero(n);
      Normal(cams, rot, trans, alpha, &jtj, &jtr);
      bool improved = false;
      for (int tries = 0; tries < 8 && !improved; ++tries) {
        Eigen::MatrixXd a = jtj;
        a.diagonal() += lambda * (jtj.diagonal().array() + 1e-9).matrix();
        const Eigen::VectorXd dx = a.ldlt().solve(-jtr);
        if (!dx.allFinite()) break;
        Eigen::VectorXd alpha_try = alpha + dx.head(k_);
        std::vector<Eigen::Matrix3d> rot_try = rot;
        std::vector<Eigen::Vector3d> trans_try = trans;
        for (int f = 0; f < nf; ++f) {
          const Eigen::Vector3d w = dx.segment<3>(k_ + 6 * f);
          if (w.norm() > 1e-12) rot_try[f] = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix() * rot[f];
          trans_try[f] += dx.segment<3>(k_ + 6 * f + 3);
        }
        const double e = Energy(cams, rot_try, trans_try, alpha_try, nullptr);
        if (e < energy) {
          improved = true;
          const double gain = energy - e;
          alpha = alpha_try;
          rot = rot_try;
          trans = trans_try;
          energy = e;
          lambda = std::max(lambda * 0.3, 1e-7);
          if (gain < 1e-10 * energy) it = options_.gauss_newton_iterations;  // converged
        } else {
          lambda *= 10;
        }
      }
      if (!improved) break;
    }
    FitResult r;
    double landmark_sq = 0;
    r.energy = Energy(cams, rot, trans, alpha, &landmark_sq);
    r.rms_px = std::sqrt(landmark_sq / std::max(1, nf));
    return r;
  }

 private:
  Eigen::Vector3d Vertex(int v, const Eigen::VectorXd& alpha) const {
    const auto& r = model_.render;
    Eigen::Vector3d x = r.mean_shape.segment<3>(3 * v).cast<double>();
    for (int k = 0; k < k_; ++k) x += r.identity_basis.block<3, 1>(3 * v, k).cast<double>() * alpha[k];
    return x;
  }
  double Scale(const gpu::PinholeCamera& cam) const { return 640.0 / cam.width; }

  // E = w_lan sum_frames sum_points weight |offset (640-wide px)|^2 + w_id sum (alpha / sigma)^2;
  // *landmark_sq (optional) gets the weighted squared offsets summed over frames.
  double Energy(const std::vector<gpu::PinholeCamera>& cams, const std::vector<Eigen::Matrix3d>& rot,
                const std::vector<Eigen::Vector3d>& trans, const Eigen::VectorXd& alpha, double* landmark_sq) const {
    double sq = 0;
    for (size_t f = 0; f < frames_.size(); ++f) {
      const FrameLandmarks& fl = frames_[f];
      for (size_t i = 0; i < fl.vertices.size(); ++i) {
        const Eigen::Vector3d x = rot[f] * Vertex(fl.vertices[i], alpha) + trans[f];
        if (!(x.z() > 0.01)) return std::numeric_limits<double>::infinity();
        const Eigen::Vector2d d = (internal::project(cams[f], x) - fl.uv[i]) * Scale(cams[f]);
        sq += fl.weight[i] * d.squaredNorm();
      }
    }
    if (landmark_sq) *landmark_sq = sq;
    double prior = 0;
    for (int k = 0; k < k_; ++k) prior += std::pow(alpha[k] / model_.identity_sigma[k], 2);
    return options_.w_landmarks * sq + options_.w_identity * prior;
  }

  // J^T J and J^T r of the energy above at the current point; unknowns [alpha | (omega, t) per frame],
  // omega a rotation applied on the left of R. A landmark's rows touch alpha and its own frame's
  // six unknowns only, so each frame's rows are stacked over those k + 6 columns and multiplied
  // once (one matrix product per frame instead of a dense n x n update per landmark, which made
  // this search a sixth of a short `reenact` run), then added into the frame's blocks.
  void Normal(const std::vector<gpu::PinholeCamera>& cams, const std::vector<Eigen::Matrix3d>& rot,
              const std::vector<Eigen::Vector3d>& trans, const Eigen::VectorXd& alpha, Eigen::MatrixXd* jtj,
              Eigen::VectorXd* jtr) const {
    const auto& r = model_.render;
    const int local = k_ + 6;
    Eigen::MatrixXd j;
    Eigen::VectorXd res;
    for (size_t f = 0; f < frames_.size(); ++f) {
      const FrameLandmarks& fl = frames_[f];
      const gpu::PinholeCamera& c = cams[f];
      const int off = k_ + 6 * static_cast<int>(f);
      const int rows = 2 * static_cast<int>(fl.vertices.size());
      j.resize(rows, local);
      res.resize(rows);
      for (size_t i = 0; i < fl.vertices.size(); ++i) {
        const int v = fl.vertices[i];
        const Eigen::Vector3d rx = rot[f] * Vertex(v, alpha);
        const Eigen::Vector3d x = rx + trans[f];
        const double s = std::sqrt(options_.w_landmarks * fl.weight[i]) * Scale(c);
        Eigen::Matrix<double, 2, 3> dp;
        dp << c.fx / x.z(), 0, -c.fx * x.x() / (x.z() * x.z()), 0, c.fy / x.z(), -c.fy * x.y() / (x.z() * x.z());
        dp *= s;
        const int row = 2 * static_cast<int>(i);
        res.segment<2>(row) = (internal::project(c, x) - fl.uv[i]) * s;
        j.block(row, 0, 2, k_).noalias() = (dp * rot[f]) * r.identity_basis.block(3 * v, 0, 3, k_).cast<double>();
        j.block<2, 3>(row, k_) = -dp * skew(rx);
        j.block<2, 3>(row, k_ + 3) = dp;
      }
      // J^T J from its lower triangle (a symmetric rank update: half the product's work, which
      // was most of this search's time), mirrored.
      Eigen::MatrixXd a = Eigen::MatrixXd::Zero(local, local);
      a.selfadjointView<Eigen::Lower>().rankUpdate(j.transpose());
      a.triangularView<Eigen::StrictlyUpper>() = a.transpose();
      const Eigen::VectorXd b = j.transpose() * res;
      jtj->topLeftCorner(k_, k_) += a.topLeftCorner(k_, k_);
      jtj->block(0, off, k_, 6) += a.topRightCorner(k_, 6);
      jtj->block(off, 0, 6, k_) += a.bottomLeftCorner(6, k_);
      jtj->block<6, 6>(off, off) += a.bottomRightCorner<6, 6>();
      jtr->head(k_) += b.head(k_);
      jtr->segment<6>(off) += b.tail<6>();
    }
    for (int k = 0; k < k_; ++k) {
      const double w = options_.w_identity / std::pow(static_cast<double>(model_.identity_sigma[k]), 2);
      (*jtj)(k, k) += w;
      (*jtr)[k] += w * alpha[k];
    }
  }

  const TrackerModel& model_;
  std::vector<FrameLandmarks> frames_;
  FocalLengthOptions options_;
  int k_;
};

}  // namespace

FovInterval FieldsOfViewWithin(std::vector<std::pair<double, double>> samples, double bound) {
  std::sort(samples.begin(), samples.end());
  auto within = [&](size_t i) { return std::isfinite(samples[i].second) && samples[i].second <= bound; };
  auto crossing = [&](size_t inside, size_t outside) {
    const auto& [f_in, e_in] = samples[inside];
    const auto& [f_out, e_out] = samples[outside];
    if (!std::isfinite(e_out)) return f_out;
    return f_in + (f_out - f_in) * (bound - e_in) / (e_out - e_in);
  };
  FovInterval u;
  size_t lo = samples.size(), hi = 0;
  for (size_t i = 0; i < samples.size(); ++i) {
    if (!within(i)) continue;
    lo = std::min(lo, i);
    hi = i;
  }
  if (lo == samples.size()) return u;  // nothing within (cannot happen: the best is)
  u.bounded = lo > 0 && hi + 1 < samples.size();
  u.low = lo > 0 ? crossing(lo, lo - 1) : samples[lo].first;
  u.high = hi + 1 < samples.size() ? crossing(hi, hi + 1) : samples[hi].first;
  return u;
}

int SecondEnergyValley(const std::vector<std::pair<double, double>>& grid, int best, double bound) {
  const int n = static_cast<int>(grid.size());
  auto energy = [&](int i) {
    const double e = grid[static_cast<size_t>(i)].second;
    return std::isfinite(e) ? e : std::numeric_limits<double>::max();
  };
  for (const int dir : {1, -1}) {
    int lowest = dir > 0 ? 0 : n - 1;
    for (int i = lowest; i != best; i += dir) {
      if (energy(i) < energy(lowest)) lowest = i;
      if (energy(i) > energy(lowest) + bound) return lowest;
    }
  }
  return -1;
}

FocalLengthEstimate EstimateFocalLength(const TrackerModel& model, const std::vector<InputFrame>& frames,
                                        const FocalLengthOptions& options) {
  const auto t0 = internal::Clock::now();
  FocalLengthEstimate out;
  out.horizontal_fov_deg = options.fallback_fov_deg;
  std::string why;
  if (!options.IsValid(&why)) {
    out.message = why;
    return out;
  }
  auto fallback = [&](const std::string& reason) {
    out.estimated = false;
    out.horizontal_fov_deg = options.fallback_fov_deg;
    out.message = reason + internal::format("; assuming %.0f degrees", options.fallback_fov_deg);
    out.ms = ms_since(t0);
    return out;
  };
  std::vector<FrameLandmarks> usable;
  for (const InputFrame& f : frames) {
    std::string frame_why;
    if (!f.camera.IsValid(&frame_why)) continue;
    FrameLandmarks fl = collect(model, f, options.min_landmark_confidence);
    if (fl.vertices.size() >= 12) usable.push_back(std::move(fl));
  }
  out.frames = static_cast<int>(usable.size());
  if (usable.empty()) return fallback("focal length not estimated: no calibration frame has 12 usable inner landmarks");
  const LandmarkFit fit(model, std::move(usable), options);

  // The grid, then a golden-section search in the bracket around its best.
  const int g = options.grid_points;
  std::vector<FitResult> grid(g);
  int best = -1;
  double e_min = std::numeric_limits<double>::infinity();
  auto grid_fov = [&](int i) { return options.min_fov_deg + (options.max_fov_deg - options.min_fov_deg) * i / (g - 1); };
  // The grid's fits are independent: side by side on the pool (the calibration waits for this
  // search, and the live session's calibration has the other core idle).
  ParallelFor(g, ResolvedThreadCount(options.threads), [&](int i) { grid[static_cast<size_t>(i)] = fit.Solve(grid_fov(i)); });
  for (int i = 0; i < g; ++i) {
    const double fov = grid_fov(i);
    out.energy_by_fov.emplace_back(fov, grid[i].energy);
    if (!std::isfinite(grid[i].energy)) continue;
    if (grid[i].energy < e_min) {
      e_min = grid[i].energy;
      best = i;
    }
  }
  if (best < 0) return fallback("focal length not estimated: the landmarks could not be fitted at any field of view");
  const double step = (options.max_fov_deg - options.min_fov_deg) / (g - 1);
  if (best == 0 || best == g - 1)
    return fallback(internal::format("focal length not estimated: the landmarks fit best at the end of the search range (%.0f degrees)",
                               options.min_fov_deg + step * best));
  double a = options.min_fov_deg + step * (best - 1), b = options.min_fov_deg + step * (best + 1);
  const double phi = 0.5 * (std::sqrt(5.0) - 1.0);
  double c = b - phi * (b - a), d = a + phi * (b - a);
  FitResult fc = fit.Solve(c), fd = fit.Solve(d);
  std::vector<std::pair<double, double>> tried = out.energy_by_fov;  // (fov, energy), for the interval
  tried.emplace_back(c, fc.energy);
  tried.emplace_back(d, fd.energy);
  for (int it = 0; it < options.refine_iterations; ++it) {
    if (fc.energy < fd.energy) {
      b = d;
      d = c;
      fd = fc;
      c = b - phi * (b - a);
      fc = fit.Solve(c);
      tried.emplace_back(c, fc.energy);
    } else {
      a = c;
      c = d;
      fc = fd;
      d = a + phi * (b - a);
      fd = fit.Solve(d);
      tried.emplace_back(d, fd.energy);
    }
  }
  FitResult chosen = grid[best];
  double fov = options.min_fov_deg + step * best;
  if (fc.energy < chosen.energy) chosen = fc, fov = c;
  if (fd.energy < chosen.energy) chosen = fd, fov = d;
  out.energy = chosen.energy;
  out.landmark_error_px = chosen.rms_px;
  if (!(chosen.rms_px <= options.max_landmark_rms_px))
    return fallback(internal::format("focal length not estimated: the landmarks are %.1f px RMS from the best fit (%.0f degrees), "
                               "too noisy to read the lens", chosen.rms_px, fov));
  // The landmarks' noise per degree of freedom (the landmark term the best fit leaves, spread over
  // the residuals less the unknowns; at least 10, so that a frame or two with few points cannot make
  // the bound a multiple of the energy), and the energy rise it allows (a profile likelihood's).
  const double noise =
      options.w_landmarks * chosen.rms_px * chosen.rms_px * out.frames / std::max(10, fit.DegreesOfFreedom());
  const double bound = options.confidence_chi2 * noise;
  const int hump = SecondEnergyValley(out.energy_by_fov, best, bound);
  if (hump >= 0)
    return fallback(internal::format("focal length not estimated: the landmark fits have two valleys, near %.0f and "
                                     "%.0f degrees, with a rise beyond the landmarks' noise between them",
                                     out.energy_by_fov[static_cast<size_t>(hump)].first, fov));
  const FovInterval u = FieldsOfViewWithin(std::move(tried), chosen.energy + bound);
  out.fov_low_deg = u.low;
  out.fov_high_deg = u.high;
  const double spread = std::max(fov - u.low, u.high - fov);
  if (!u.bounded || spread > options.max_relative_uncertainty * fov)
    return fallback(internal::format("focal length not estimated: the landmarks fit every field of view from %.0f to "
                                     "%.0f degrees%s within their noise (best %.0f): they do not pin the lens down",
                                     u.low, u.high, u.bounded ? "" : " (an end of the search range)", fov));
  out.estimated = true;
  out.horizontal_fov_deg = fov;
  out.ms = ms_since(t0);
  out.message = internal::format("estimated %.1f degrees horizontal field of view (%.0f-%.0f within the landmarks' "
                                 "noise)", fov, u.low, u.high) +
                " from " + std::to_string(out.frames) +
                internal::format(" calibration frames (landmarks %.2f px RMS, %.0f ms)", chosen.rms_px, out.ms);
  return out;
}

}  // namespace face_reenact::tracker
