// The run-long tally of fit_agreement.h (MeasureFitAgreement itself is in pose_init.cc, beside
// the landmark pose it compares with).
#include <algorithm>
#include <cmath>
#include <numeric>

#include "face_reenact/tracker/fit_agreement.h"

#include "face_reenact/common/json_number.h"

namespace face_reenact::tracker {

Distribution Summarize(std::vector<double> values) {
  values.erase(std::remove_if(values.begin(), values.end(), [](double v) { return std::isnan(v); }), values.end());
  Distribution d;
  d.count = static_cast<int>(values.size());
  if (values.empty()) return d;
  std::sort(values.begin(), values.end());
  d.mean = std::accumulate(values.begin(), values.end(), 0.0) / static_cast<double>(values.size());
  // Nearest-rank quantiles: each is one of the measured values.
  auto rank = [&](double q) {
    const size_t k = static_cast<size_t>(std::ceil(q * static_cast<double>(values.size())));
    return values[std::clamp<size_t>(k, 1, values.size()) - 1];
  };
  d.median = rank(0.5);
  d.p95 = rank(0.95);
  d.max = values.back();
  return d;
}

nlohmann::json to_json(const Distribution& d) {
  return {{"frames", d.count},
          {"mean", json_number(d.mean)},
          {"median", json_number(d.median)},
          {"p95", json_number(d.p95)},
          {"max", json_number(d.max)}};
}

FitAgreementTally::FitAgreementTally(FitAgreementOptions yardstick) { s_.yardstick = yardstick; }

void FitAgreementTally::Add(int64_t frame, bool has_fit, bool refused, const FitAgreement& a, const std::string& message) {
  if (refused) ++s_.refused_frames;
  if (!has_fit) return;
  ++s_.fit_frames;
  pose_.push_back(a.pose_disagreement_deg);
  nme_.push_back(a.landmark_nme);
  speed_.push_back(a.rotation_speed_deg_s);
  brows_.push_back(a.nme_brows);
  nose_.push_back(a.nme_nose);
  eyes_.push_back(a.nme_eyes);
  mouth_.push_back(a.nme_mouth);
  const FitAgreementOptions& y = s_.yardstick;
  auto note = [&](int* count, const char* what, double value) {
    ++*count;
    if (s_.beyond.size() < kMaxListed) s_.beyond.push_back({frame, what, value, message});
  };
  if (y.max_pose_disagreement_deg > 0 && a.pose_disagreement_deg > y.max_pose_disagreement_deg)
    note(&s_.beyond_pose, "pose", a.pose_disagreement_deg);
  if (y.max_landmark_nme > 0 && a.landmark_nme > y.max_landmark_nme) note(&s_.beyond_landmarks, "landmarks", a.landmark_nme);
  if (y.max_rotation_speed_deg_s > 0 && a.rotation_speed_deg_s > y.max_rotation_speed_deg_s)
    note(&s_.beyond_rotation_speed, "rotation speed", a.rotation_speed_deg_s);
}

FitAgreementTally::Summary FitAgreementTally::summary() const {
  Summary s = s_;
  s.pose_disagreement_deg = Summarize(pose_);
  s.landmark_nme = Summarize(nme_);
  s.rotation_speed_deg_s = Summarize(speed_);
  s.nme_brows = Summarize(brows_);
  s.nme_nose = Summarize(nose_);
  s.nme_eyes = Summarize(eyes_);
  s.nme_mouth = Summarize(mouth_);
  return s;
}

}  // namespace face_reenact::tracker
