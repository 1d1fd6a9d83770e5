#include "face_reenact/tracker/eye_openness.h"

#include "face_reenact/model/face_model.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <vector>

namespace face_reenact::tracker {

bool EyeOpennessOptions::IsValid(std::string* why) const {
  auto fail = [&](const char* m) {
    if (why) *why = std::string("eye openness options: ") + m;
    return false;
  };
  if (history_frames < 1 || history_frames > 100000) return fail("history_frames must be 1..100000");
  if (!(open_percentile >= 0.0 && open_percentile <= 1.0)) return fail("open_percentile must be in [0, 1]");
  if (min_history < 1 || min_history > history_frames) return fail("min_history must be 1..history_frames");
  if (!(dead_zone >= 0.0 && closed_ratio >= 0.0 && closed_ratio < 1.0 - dead_zone))
    return fail("need 0 <= closed_ratio < 1 - dead_zone, dead_zone >= 0");
  if (!(min_confidence >= 0.f && min_confidence <= 1.f)) return fail("min_confidence must be in [0, 1]");
  return true;
}

double EyeAspectRatio(const std::array<Eigen::Vector2f, 6>& p, const Eigen::Vector2f* down) {
  const double width = (p[0] - p[3]).norm();
  if (!(width > 1e-6) || !std::isfinite(width)) return std::numeric_limits<double>::quiet_NaN();
  if (down) {
    const double a = std::max(0.f, (p[5] - p[1]).dot(*down)), b = std::max(0.f, (p[4] - p[2]).dot(*down));
    return (a + b) / (2.0 * width);
  }
  return ((p[1] - p[5]).norm() + (p[2] - p[4]).norm()) / (2.0 * width);
}

EyeOpeningCurve EyeOpeningCurve::FromModel(const TrackerModel& model, int steps) {
  EyeOpeningCurve c;
  const gpu::RenderModel& rm = model.render;
  std::array<int, 12> vertex;
  vertex.fill(-1);
  for (const TrackerLandmark& l : model.landmarks)
    if (l.ibug_index >= 36 && l.ibug_index <= 47 && l.vertex >= 0 && l.vertex < rm.num_vertices())
      vertex[size_t(l.ibug_index - 36)] = l.vertex;
  if (std::any_of(vertex.begin(), vertex.end(), [](int v) { return v < 0; }) || steps < 1) return c;
  const Eigen::Vector2f down(0.f, 1.f);  // the model's +y is up the face; the image's y runs down
  for (int e = 0; e < 2; ++e) {
    const int blink = arkit_blendshape_index(e == 0 ? "eyeBlinkLeft" : "eyeBlinkRight");
    if (blink < 0 || blink >= model.num_expression()) return EyeOpeningCurve{};
    const int first = e == 0 ? 6 : 0;  // iBUG 42-47 are the person's left eye
    double open = 0;
    for (int k = 0; k <= steps; ++k) {
      const float w = float(k) / float(steps);
      std::array<Eigen::Vector2f, 6> p;
      for (int i = 0; i < 6; ++i) {
        const int v = vertex[size_t(first + i)];
        const Eigen::Vector3f x = rm.mean_shape.segment<3>(3 * v) + w * rm.expression_basis.block(3 * v, blink, 3, 1);
        p[size_t(i)] = Eigen::Vector2f(x.x(), -x.y());
      }
      const double ratio = EyeAspectRatio(p, &down);
      if (k == 0) open = ratio;
      if (!(open > 0.0) || !std::isfinite(ratio)) return EyeOpeningCurve{};
      const double f = ratio / open;
      c.fraction[size_t(e)].push_back(k == 0 ? 1.0 : std::min(f, c.fraction[size_t(e)].back()));
    }
  }
  return c;
}

float EyeOpeningCurve::WeightFor(int eye, double opening) const {
  opening = std::clamp(opening, 0.0, 1.0);
  if (empty()) return static_cast<float>(1.0 - opening);
  const std::vector<double>& f = fraction[size_t(eye)];
  const double step = 1.0 / double(f.size() - 1);
  for (size_t k = 1; k < f.size(); ++k) {
    if (f[k] > opening) continue;
    // f[k - 1] > opening >= f[k]: between the two samples.
    const double t = f[k - 1] > f[k] ? (f[k - 1] - opening) / (f[k - 1] - f[k]) : 0.0;
    return static_cast<float>((double(k - 1) + t) * step);
  }
  return 1.f;  // the model's eye never shuts that far: as far as it goes
}

EyeOpennessReader::EyeOpennessReader(const EyeOpennessOptions& options, const TrackerModel* model)
    : options_(options),
      curve_(model ? EyeOpeningCurve::FromModel(*model) : EyeOpeningCurve{}),
      blink_index_{arkit_blendshape_index("eyeBlinkLeft"), arkit_blendshape_index("eyeBlinkRight")} {}

void EyeOpennessReader::WriteBlink(const EyeOpennessReading& reading, Eigen::VectorXf* delta) const {
  for (int e = 0; e < 2; ++e) {
    const int k = blink_index_[size_t(e)];
    if (k >= 0 && k < delta->size()) (*delta)[k] = reading.blink[size_t(e)];
  }
}

void EyeOpennessReader::Reset() {
  for (auto& h : history_) h.clear();
}

EyeOpennessReading EyeOpennessReader::Read(const InputFrame& frame) {
  EyeOpennessReading r;
  if (!options_.enabled) {
    r.message = "off";
    return r;
  }
  // iBUG 42-47: the person's left eye (eyeBlinkLeft), 36-41 the right.
  constexpr std::array<int, 2> kFirst = {42, 36};
  std::array<std::array<Eigen::Vector2f, 6>, 2> points;
  std::array<int, 2> found{};
  // Down the face: from the eyes' middle towards the mouth's (iBUG 48-67), perpendicular to the
  // line through the eyes; without the mouth the unsigned ratio.
  Eigen::Vector2f mouth = Eigen::Vector2f::Zero();
  int mouth_points = 0;
  for (const InputLandmark& l : frame.landmarks) {
    if (l.ibug_index >= 48 && l.ibug_index <= 67 && l.confidence > 0.f && l.position.allFinite()) {
      mouth += l.position;
      ++mouth_points;
    }
  }
  for (const InputLandmark& l : frame.landmarks) {
    for (int e = 0; e < 2; ++e) {
      const int k = l.ibug_index - kFirst[size_t(e)];
      if (k < 0 || k >= 6 || !(l.confidence >= options_.min_confidence) || !l.position.allFinite()) continue;
      points[size_t(e)][size_t(k)] = l.position;
      found[size_t(e)] |= 1 << k;
    }
  }
  for (int e = 0; e < 2; ++e) {
    if (found[size_t(e)] != 0x3f) {
      r.message = "no confident eye points";
      return r;
    }
  }
  std::optional<Eigen::Vector2f> down;
  if (mouth_points > 0) {
    const Eigen::Vector2f left_eye = 0.5f * (points[0][0] + points[0][3]), right_eye = 0.5f * (points[1][0] + points[1][3]);
    const Eigen::Vector2f across = left_eye - right_eye;
    Eigen::Vector2f n(-across.y(), across.x());
    const Eigen::Vector2f to_mouth = mouth / float(mouth_points) - 0.5f * (left_eye + right_eye);
    if (n.norm() > 1e-6f && std::abs(n.dot(to_mouth)) > 1e-6f) {
      n.normalize();
      down = n.dot(to_mouth) > 0.f ? n : Eigen::Vector2f(-n);
    }
  }
  for (int e = 0; e < 2; ++e) {
    r.ratio[size_t(e)] = EyeAspectRatio(points[size_t(e)], down ? &*down : nullptr);
    if (!std::isfinite(r.ratio[size_t(e)])) {
      r.message = "degenerate eye points";
      return r;
    }
  }
  for (int e = 0; e < 2; ++e) {
    std::deque<double>& h = history_[size_t(e)];
    h.push_back(r.ratio[size_t(e)]);
    while (static_cast<int>(h.size()) > options_.history_frames) h.pop_front();
  }
  if (static_cast<int>(history_[0].size()) < options_.min_history) {
    r.message = "learning the open eye (" + std::to_string(history_[0].size()) + " of " +
                std::to_string(options_.min_history) + " frames)";
    return r;
  }
  for (int e = 0; e < 2; ++e) {
    std::vector<double> sorted(history_[size_t(e)].begin(), history_[size_t(e)].end());
    const size_t k = std::min(sorted.size() - 1, static_cast<size_t>(options_.open_percentile * double(sorted.size() - 1) + 0.5));
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(k), sorted.end());
    const double open = sorted[k];
    r.open_ratio[size_t(e)] = open;
    const double from = (1.0 - options_.dead_zone) * open, to = options_.closed_ratio * open;
    const double opening = open > 0.0 ? std::clamp((r.ratio[size_t(e)] - to) / (from - to), 0.0, 1.0) : 1.0;
    r.blink[size_t(e)] = opening >= 1.0 ? 0.f : curve_.WeightFor(e, opening);
  }
  r.ok = true;
  return r;
}

}  // namespace face_reenact::tracker
