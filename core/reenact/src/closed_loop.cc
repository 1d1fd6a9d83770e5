// The reenactment's yardsticks (closed_loop.h).
#include "face_reenact/reenact/closed_loop.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"

#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/reenact/transfer.h"

namespace face_reenact::reenact {

double ExpressionError(const Eigen::VectorXf& got, const Eigen::VectorXf& truth) {
  double sum = 0;
  for (int i = 0; i < kNumExpressionWeights; ++i) sum += std::abs(expression_weight(got, i) - expression_weight(truth, i));
  return sum / kNumExpressionWeights;
}

class ClosedLoopScore::IdentityMeter {
 public:
  IdentityMeter(const tracker::TrackerModel& model, const gpu::PinholeCamera& camera)
      : model_(model), renderer_(model_.render), camera_(camera) {}
  const tracker::IdentityErrors& Compare(const Eigen::VectorXf& fit, const Eigen::VectorXf& truth) {
    if (!has_ || fit.size() != fit_.size() || fit != fit_ || truth.size() != truth_.size() || truth != truth_) {
      last_ = tracker::CompareIdentities(renderer_, model_, fit, truth, camera_, kDistanceM);
      fit_ = fit;
      truth_ = truth;
      has_ = true;
    }
    return last_;
  }

 private:
  static constexpr float kDistanceM = 0.6f;  // the neutral faces are compared 0.6 m in front of the camera
  const tracker::TrackerModel& model_;
  gpu::CpuRenderer renderer_;
  gpu::PinholeCamera camera_;
  bool has_ = false;
  Eigen::VectorXf fit_, truth_;
  tracker::IdentityErrors last_;
};

double ClosedLoopScore::Mean::value() const { return n ? sum / n : std::numeric_limits<double>::quiet_NaN(); }

ClosedLoopScore::ClosedLoopScore(tracker::TrackerModel model, const gpu::PinholeCamera& camera)
    : model_(std::move(model)),
      target_identity_(std::make_unique<IdentityMeter>(model_, camera)),
      loop_identity_(std::make_unique<IdentityMeter>(model_, camera)) {}

ClosedLoopScore::~ClosedLoopScore() = default;

void ClosedLoopScore::AddSource(const tracker::TrackedFrame& source, bool source_calibrated,
                                const Eigen::VectorXf& source_truth) {
  if (source.has_parameters && tracker::tracking_status_has_fit(source.status) && source_calibrated)
    source_.add(ExpressionError(source.params.delta, source_truth));
}

void ClosedLoopScore::AddTargetIdentity(const Eigen::VectorXf& fitted_alpha, const Eigen::VectorXf& true_alpha) {
  const tracker::IdentityErrors& e = target_identity_->Compare(fitted_alpha, true_alpha);
  target_identity_mm_.add(e.surface_mm_mean);
  target_identity_vertex_.add(e.vertex_mm_mean);
}

void ClosedLoopScore::AddLoop(const tracker::TrackedFrame& loop, bool loop_calibrated, const Eigen::VectorXf& loop_alpha,
                              const Eigen::VectorXf& source_truth, const Eigen::VectorXf& rendered_expression,
                              const Eigen::VectorXf& target_true_alpha) {
  if (!loop_calibrated || !loop.has_parameters || !tracker::tracking_status_has_fit(loop.status)) return;
  // ExpressionError, one blendshape at a time (kept per blendshape too).
  blendshape_error_sums_.resize(kNumExpressionWeights, 0.0);
  double sum = 0;
  for (int i = 0; i < kNumExpressionWeights; ++i) {
    const double e = std::abs(expression_weight(loop.params.delta, i) - expression_weight(source_truth, i));
    blendshape_error_sums_[static_cast<size_t>(i)] += e;
    sum += e;
  }
  expression_.add(sum / kNumExpressionWeights);
  rendered_.add(ExpressionError(loop.params.delta, rendered_expression));
  jaw_.add(std::abs(expression_weight(loop.params.delta, kJawOpenIndex) - expression_weight(source_truth, kJawOpenIndex)));
  const tracker::IdentityErrors& e = loop_identity_->Compare(loop_alpha, target_true_alpha);
  identity_.add(e.surface_mm_mean);
  identity_vertex_.add(e.vertex_mm_mean);
}

ClosedLoopScore::Summary ClosedLoopScore::summary() const {
  Summary s;
  s.loop_frames = expression_.n;
  s.expression_error = expression_.value();
  s.jaw_open_error = jaw_.value();
  s.expression_error_vs_rendered = rendered_.value();
  s.identity_error_mm = identity_.value();
  s.identity_vertex_error_mm = identity_vertex_.value();
  s.source_expression_error = source_.value();
  s.target_identity_error_mm = target_identity_mm_.value();
  s.target_identity_vertex_error_mm = target_identity_vertex_.value();
  if (expression_.n > 0)
    for (const double sum : blendshape_error_sums_) s.expression_error_by_blendshape.push_back(sum / expression_.n);
  return s;
}

std::vector<std::pair<std::string, double>> ClosedLoopScore::Summary::WorstBlendshapes(int n) const {
  std::vector<std::pair<std::string, double>> all;
  const auto& names = arkit_blendshape_names();
  for (size_t i = 0; i < expression_error_by_blendshape.size() && i < names.size(); ++i)
    all.emplace_back(names[i], expression_error_by_blendshape[i]);
  std::stable_sort(all.begin(), all.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
  if (static_cast<int>(all.size()) > n) all.resize(static_cast<size_t>(std::max(0, n)));
  return all;
}

FaceFidelity MeasureFaceFidelity(const cv::Mat& reference_bgr, const cv::Mat& output_bgr, const cv::Mat& mask) {
  if (reference_bgr.type() != CV_8UC3 || output_bgr.type() != CV_8UC3 || mask.type() != CV_8UC1 ||
      reference_bgr.size() != output_bgr.size() || mask.size() != reference_bgr.size())
    throw Error("face fidelity: the frames must be 8-bit BGR of one size, the mask 8-bit of that size");
  FaceFidelity f;
  f.pixels = cv::countNonZero(mask);
  if (f.pixels == 0) {
    f.psnr_db = f.ssim = std::numeric_limits<double>::quiet_NaN();
    return f;
  }
  double squared = 0;
  for (int j = 0; j < mask.rows; ++j) {
    const uchar* m = mask.ptr<uchar>(j);
    const cv::Vec3b* a = reference_bgr.ptr<cv::Vec3b>(j);
    const cv::Vec3b* b = output_bgr.ptr<cv::Vec3b>(j);
    for (int i = 0; i < mask.cols; ++i)
      if (m[i])
        for (int c = 0; c < 3; ++c) {
          const double d = static_cast<double>(a[i][c]) - static_cast<double>(b[i][c]);
          squared += d * d;
        }
  }
  const double mse = squared / (3.0 * f.pixels);
  f.psnr_db = mse > 0 ? 10.0 * std::log10(255.0 * 255.0 / mse) : std::numeric_limits<double>::infinity();
  // SSIM (Wang, Bovik, Sheikh, Simoncelli 2004): local means, variances and covariance under a
  // Gaussian window, the map averaged over the face.
  cv::Mat x, y;
  cv::cvtColor(reference_bgr, x, cv::COLOR_BGR2GRAY);
  cv::cvtColor(output_bgr, y, cv::COLOR_BGR2GRAY);
  x.convertTo(x, CV_64F);
  y.convertTo(y, CV_64F);
  const double c1 = std::pow(0.01 * 255.0, 2), c2 = std::pow(0.03 * 255.0, 2);
  auto blur = [](const cv::Mat& in) {
    cv::Mat out;
    cv::GaussianBlur(in, out, cv::Size(11, 11), 1.5);
    return out;
  };
  const cv::Mat mx = blur(x), my = blur(y);
  const cv::Mat sxx = blur(x.mul(x)) - mx.mul(mx), syy = blur(y.mul(y)) - my.mul(my), sxy = blur(x.mul(y)) - mx.mul(my);
  const cv::Mat numerator = (2.0 * mx.mul(my) + c1).mul(2.0 * sxy + c2);
  const cv::Mat denominator = (mx.mul(mx) + my.mul(my) + c1).mul(sxx + syy + c2);
  cv::Mat ssim_map;
  cv::divide(numerator, denominator, ssim_map);
  f.ssim = cv::mean(ssim_map, mask)[0];
  return f;
}

void FaceFidelityTally::Add(const FaceFidelity& f) {
  if (f.pixels <= 0 || std::isnan(f.psnr_db) || std::isnan(f.ssim)) return;
  constexpr double kEqualPsnrDb = 99.0;  // an identical face region (infinite PSNR) counts so
  const double psnr = std::min(f.psnr_db, kEqualPsnrDb);
  psnr_min_ = frames_ == 0 ? psnr : std::min(psnr_min_, psnr);
  psnr_sum_ += psnr;
  ssim_sum_ += f.ssim;
  ++frames_;
}

FaceFidelityTally::Summary FaceFidelityTally::summary() const {
  Summary s;
  s.frames = frames_;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  s.psnr_db = frames_ ? psnr_sum_ / frames_ : nan;
  s.ssim = frames_ ? ssim_sum_ / frames_ : nan;
  s.psnr_db_min = frames_ ? psnr_min_ : nan;
  return s;
}

}  // namespace face_reenact::reenact
