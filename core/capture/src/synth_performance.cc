// Identity, light and performance timelines of synthetic recordings (synth.h).
#include <algorithm>
#include <cmath>

#include "face_reenact/capture/json_checks.h"
#include "face_reenact/capture/synth.h"
#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"

namespace face_reenact::capture {
namespace jc = json_checks;
using nlohmann::json;

namespace {

enum PerformanceStream : uint64_t {
  kIdentity = 101,
  kAlbedo,
  kYaw,
  kPitch,
  kRoll,
  kTx,
  kTy,
  kTz,
  kDistance,
  kTalkGate,
  kTalkPhase,
  kSyllable,
  kBlink,
  kSmile,
  kSmileSide,
  kBrow,
  kFrown,
  kLightAzimuth,
  kLightElevation,
  kLightIntensity,
  kLightAmbient,
  kLightTint,
  kLook,
};

// The calibration turn's amplitudes: the side of the face in front of the ears, which the
// identity moves by up to 14 mm (s.d.), faces the camera at 25 degrees of yaw.
constexpr double kCalibrationTurnYawDeg = 25;
constexpr double kCalibrationTurnPitchDeg = 6;
constexpr double kCalibrationTurnShare = 0.8;  // the rest of the turn eases into the performance

void set_weight(PerformanceState& s, const char* name, double w) {
  const int k = arkit_blendshape_index(name);
  if (k < 0) throw Error(std::string("internal: unknown ARKit name ") + name);
  s.expression[k] = static_cast<float>(std::clamp(w, 0.0, 1.0));
}

}  // namespace

SynthIdentity random_identity(const FaceModel& model, uint64_t seed) {
  SynthIdentity id;
  id.alpha.resize(model.num_identity());
  for (int i = 0; i < model.num_identity(); ++i)
    id.alpha[i] = static_cast<float>(model.identity_sigma[i] * gaussian(hash_key(seed, kIdentity, static_cast<uint64_t>(i))));
  id.beta.resize(model.num_albedo());
  for (int i = 0; i < model.num_albedo(); ++i)
    id.beta[i] = static_cast<float>(model.albedo_sigma[i] * gaussian(hash_key(seed, kAlbedo, static_cast<uint64_t>(i))));
  return id;
}

SynthIdentity parse_identity(const std::string& json_text, const FaceModel& model, const std::string& what) {
  const json j = jc::parse(json_text, what);
  jc::only_keys(j, {"alpha", "beta"}, what, "");
  SynthIdentity id;
  id.alpha = Eigen::VectorXf::Zero(model.num_identity());
  id.beta = Eigen::VectorXf::Zero(model.num_albedo());
  auto read = [&](const char* key, int count, const Eigen::VectorXf& sigma, Eigen::VectorXf* out) {
    if (!j.contains(key)) return;
    if (!j[key].is_array()) jc::fail(what, key, "expected an array of numbers");
    if (static_cast<int>(j[key].size()) > count)
      jc::fail(what, key, "the model has only " + std::to_string(count) + " coefficients, got " + std::to_string(j[key].size()));
    for (size_t i = 0; i < j[key].size(); ++i) {
      const double limit = 5.0 * sigma[static_cast<int>(i)];
      (*out)[static_cast<int>(i)] = static_cast<float>(jc::number(j[key][i], what, jc::index(key, i), -limit, limit));
    }
  };
  read("alpha", model.num_identity(), model.identity_sigma, &id.alpha);
  read("beta", model.num_albedo(), model.albedo_sigma, &id.beta);
  return id;
}

std::array<float, gpu::kNumShParameters> sh_from_light(const LightState& light) {
  // Lambertian convolution weights of SH bands 0, 1, 2 (clamped cosine): pi, 2pi/3, pi/4.
  static constexpr float kBand[9] = {3.14159265f, 2.09439510f, 2.09439510f, 2.09439510f, 0.78539816f,
                                     0.78539816f, 0.78539816f, 0.78539816f, 0.78539816f};
  const Eigen::Vector3f d = light.direction.normalized();
  const auto y = gpu::sh_basis(d);
  const float y0 = gpu::sh_basis(Eigen::Vector3f(0, 0, 1))[0];
  std::array<float, gpu::kNumShParameters> g{};
  for (int c = 0; c < 3; ++c) {
    for (int k = 0; k < 9; ++k) g[static_cast<size_t>(c * 9 + k)] = light.color[c] * light.intensity * kBand[k] * y[static_cast<size_t>(k)];
    g[static_cast<size_t>(c * 9)] += light.color[c] * light.ambient / y0;
  }
  return g;
}

Eigen::Vector3f PerformanceState::euler() const {
  const float deg = static_cast<float>(M_PI / 180.0);
  return Eigen::Vector3f(static_cast<float>(M_PI) + head_deg.x() * deg, head_deg.y() * deg, head_deg.z() * deg);
}

Timeline::Timeline(std::vector<Keyframe> keys) : keys_(std::move(keys)) {
  if (keys_.empty()) throw Error("timeline: no keyframes");
  for (size_t i = 1; i < keys_.size(); ++i)
    if (!(keys_[i].time_s > keys_[i - 1].time_s)) throw Error("timeline: keyframe times must increase");
}

PerformanceState Timeline::at(double t) const {
  if (t <= keys_.front().time_s) return keys_.front().state;
  if (t >= keys_.back().time_s) return keys_.back().state;
  const auto it = std::upper_bound(keys_.begin(), keys_.end(), t, [](double v, const Keyframe& k) { return v < k.time_s; });
  const Keyframe& b = *it;
  const Keyframe& a = *(it - 1);
  const float w = static_cast<float>(smoothstep01((t - a.time_s) / (b.time_s - a.time_s)));
  PerformanceState s;
  s.expression = (1 - w) * a.state.expression + w * b.state.expression;
  s.head_deg = (1 - w) * a.state.head_deg + w * b.state.head_deg;
  s.translation = (1 - w) * a.state.translation + w * b.state.translation;
  s.light.direction = ((1 - w) * a.state.light.direction.normalized() + w * b.state.light.direction.normalized());
  if (s.light.direction.norm() < 1e-6f) s.light.direction = b.state.light.direction;
  s.light.direction.normalize();
  s.light.intensity = (1 - w) * a.state.light.intensity + w * b.state.light.intensity;
  s.light.ambient = (1 - w) * a.state.light.ambient + w * b.state.light.ambient;
  s.light.color = (1 - w) * a.state.light.color + w * b.state.light.color;
  return s;
}

Timeline parse_script(const std::string& json_text, const std::string& what) {
  const json j = jc::parse(json_text, what);
  jc::only_keys(j, {"keyframes", "comment"}, what, "");
  jc::require_keys(j, {"keyframes"}, what, "");
  const json& ks = j["keyframes"];
  if (!ks.is_array() || ks.empty()) jc::fail(what, "keyframes", "expected a non-empty array of keyframes");
  if (ks.size() > 100000) jc::fail(what, "keyframes", "too many keyframes");
  std::vector<Keyframe> keys;
  PerformanceState previous;
  for (size_t i = 0; i < ks.size(); ++i) {
    const std::string kp = jc::index("keyframes", i);
    const json& k = ks[i];
    jc::only_keys(k, {"time", "expression", "head", "light"}, what, kp);
    jc::require_keys(k, {"time"}, what, kp);
    Keyframe key;
    key.time_s = jc::number(k["time"], what, jc::join(kp, "time"), 0.0, 1e6);
    if (!keys.empty() && !(key.time_s > keys.back().time_s))
      jc::fail(what, jc::join(kp, "time"), "keyframe times must increase");
    key.state = previous;
    key.state.expression.setZero();  // unlisted blendshapes are 0 in every keyframe
    if (k.contains("expression")) {
      const std::string ep = jc::join(kp, "expression");
      jc::require_object(k["expression"], what, ep);
      for (auto it = k["expression"].begin(); it != k["expression"].end(); ++it) {
        const int idx = arkit_blendshape_index(it.key());
        if (idx < 0) jc::fail(what, jc::join(ep, it.key()), "unknown ARKit blendshape name");
        key.state.expression[idx] = static_cast<float>(jc::number(it.value(), what, jc::join(ep, it.key()), 0.0, 1.0));
      }
    }
    if (k.contains("head")) {
      const std::string hp = jc::join(kp, "head");
      const json& h = k["head"];
      jc::only_keys(h, {"pitch_deg", "yaw_deg", "roll_deg", "translation"}, what, hp);
      if (h.contains("pitch_deg")) key.state.head_deg.x() = float(jc::number(h["pitch_deg"], what, jc::join(hp, "pitch_deg"), -60, 60));
      if (h.contains("yaw_deg")) key.state.head_deg.y() = float(jc::number(h["yaw_deg"], what, jc::join(hp, "yaw_deg"), -90, 90));
      if (h.contains("roll_deg")) key.state.head_deg.z() = float(jc::number(h["roll_deg"], what, jc::join(hp, "roll_deg"), -60, 60));
      if (h.contains("translation")) {
        const std::string tp = jc::join(hp, "translation");
        const auto t = jc::numbers(h["translation"], what, tp, -5.0, 5.0, 3, 3);
        if (!(t[2] >= 0.3)) jc::fail(what, jc::index(tp, 2), "the head must be at least 0.3 m in front of the camera");
        key.state.translation = Eigen::Vector3f(float(t[0]), float(t[1]), float(t[2]));
      }
    }
    if (k.contains("light")) {
      const std::string lp = jc::join(kp, "light");
      const json& l = k["light"];
      jc::only_keys(l, {"direction", "intensity", "ambient", "color"}, what, lp);
      if (l.contains("direction")) {
        const auto d = jc::numbers(l["direction"], what, jc::join(lp, "direction"), -1e3, 1e3, 3, 3);
        const Eigen::Vector3f v(static_cast<float>(d[0]), static_cast<float>(d[1]), static_cast<float>(d[2]));
        if (v.norm() < 1e-6f) jc::fail(what, jc::join(lp, "direction"), "must not be the zero vector");
        key.state.light.direction = v.normalized();
      }
      if (l.contains("intensity")) key.state.light.intensity = float(jc::number(l["intensity"], what, jc::join(lp, "intensity"), 0, 10));
      if (l.contains("ambient")) key.state.light.ambient = float(jc::number(l["ambient"], what, jc::join(lp, "ambient"), 0, 10));
      if (l.contains("color")) {
        const auto c = jc::numbers(l["color"], what, jc::join(lp, "color"), 0.0, 10.0, 3, 3);
        key.state.light.color = Eigen::Vector3f(float(c[0]), float(c[1]), float(c[2]));
      }
    }
    previous = key.state;
    keys.push_back(std::move(key));
  }
  return Timeline(std::move(keys));
}

Timeline random_timeline(uint64_t seed, int frames, double fps, double calibration_turn_s) {
  if (frames < 1 || !(fps > 0)) throw Error("random_timeline: need frames >= 1 and fps > 0");
  if (!(calibration_turn_s >= 0) || calibration_turn_s > 60) throw Error("random_timeline: calibration turn must be 0..60 s");
  auto key = [&](uint64_t stream) { return hash_key(seed, stream); };
  // Per-recording constants.
  const double distance = 0.7 + 0.45 * uniform01(key(kDistance));
  // Blink times: intervals of 2-6 s.
  std::vector<double> blinks;
  const double duration = frames / fps;
  for (double t = 0.5 + 2.0 * uniform01(hash_key(seed, kBlink, 0)); t < duration + 1; ) {
    blinks.push_back(t);
    t += 2.0 + 4.0 * uniform01(hash_key(seed, kBlink, blinks.size()));
  }
  std::vector<Keyframe> keys;
  keys.reserve(static_cast<size_t>(frames));
  for (int i = 0; i < frames; ++i) {
    const double frame_t = i / fps;
    // During the calibration turn the performance is held at its first state (t = 0) and only
    // the head turns; the performance starts when the turn ends.
    const double t = std::max(0.0, frame_t - calibration_turn_s);
    Keyframe k;
    k.time_s = frame_t;
    PerformanceState& s = k.state;
    // Head: slow looks around, within the documented ranges.
    s.head_deg.y() = static_cast<float>(std::clamp(14.0 * smooth_noise(key(kYaw), t, 2.2), -30.0, 30.0));
    s.head_deg.x() = static_cast<float>(std::clamp(6.0 * smooth_noise(key(kPitch), t, 1.8), -15.0, 15.0));
    s.head_deg.z() = static_cast<float>(std::clamp(4.0 * smooth_noise(key(kRoll), t, 2.6), -10.0, 10.0));
    s.translation = Eigen::Vector3f(static_cast<float>(0.04 * smooth_noise(key(kTx), t, 3.0)),
                                    static_cast<float>(-0.07 + 0.02 * smooth_noise(key(kTy), t, 3.0)),
                                    static_cast<float>(distance + 0.05 * smooth_noise(key(kTz), t, 4.0)));
    // Speech: bursts (gate) of syllables at ~4-5 Hz driving jaw and lips.
    const double gate = smoothstep01((smooth_noise(key(kTalkGate), t, 1.6) + 0.3) * 2.0);
    const double phase = 2 * M_PI * 4.3 * t + 2.5 * smooth_noise(key(kTalkPhase), t, 0.6);
    const double syllable = std::pow(std::max(0.0, std::sin(phase)), 1.5);
    const double amp = 0.5 + 0.2 * smooth_noise(key(kSyllable), t, 0.4);
    set_weight(s, "jawOpen", gate * amp * syllable * 0.55);
    set_weight(s, "mouthFunnel", gate * 0.35 * std::max(0.0, smooth_noise(hash_key(seed, kSyllable, 1), t, 0.35)));
    set_weight(s, "mouthPucker", gate * 0.3 * std::max(0.0, smooth_noise(hash_key(seed, kSyllable, 2), t, 0.45) - 0.3));
    set_weight(s, "mouthLowerDownLeft", gate * syllable * 0.25);
    set_weight(s, "mouthLowerDownRight", gate * syllable * 0.25);
    set_weight(s, "mouthUpperUpLeft", gate * 0.15 * std::max(0.0, std::sin(phase + 1.0)));
    set_weight(s, "mouthUpperUpRight", gate * 0.15 * std::max(0.0, std::sin(phase + 1.0)));
    set_weight(s, "mouthClose", gate * 0.15 * std::max(0.0, -std::sin(phase)));
    // Blinks: 80 ms closing, 170 ms opening.
    double blink = 0;
    for (double b : blinks) {
      const double dt = frame_t - b;  // blinks are involuntary: they go on through the turn
      if (dt > -0.08 && dt < 0) blink = std::max(blink, 1 + dt / 0.08);
      else if (dt >= 0 && dt < 0.17) blink = std::max(blink, 1 - dt / 0.17);
    }
    set_weight(s, "eyeBlinkLeft", blink);
    set_weight(s, "eyeBlinkRight", blink);
    // Smiles (slightly asymmetric), brow raises, occasional frowns.
    const double smile = std::clamp((smooth_noise(key(kSmile), t, 2.8) - 0.2) * 1.1, 0.0, 1.0);
    const double side = 0.15 * smooth_noise(key(kSmileSide), t, 3.0);
    set_weight(s, "mouthSmileLeft", smile * (1 + side));
    set_weight(s, "mouthSmileRight", smile * (1 - side));
    set_weight(s, "cheekSquintLeft", 0.5 * smile);
    set_weight(s, "cheekSquintRight", 0.5 * smile);
    const double brow = std::clamp((smooth_noise(key(kBrow), t, 1.7) - 0.5) * 1.4, 0.0, 1.0);
    set_weight(s, "browInnerUp", brow);
    set_weight(s, "browOuterUpLeft", 0.8 * brow);
    set_weight(s, "browOuterUpRight", 0.8 * brow);
    const double frown = std::clamp((smooth_noise(key(kFrown), t, 3.3) - 1.0) * 1.2, 0.0, 0.8);
    set_weight(s, "browDownLeft", frown);
    set_weight(s, "browDownRight", frown);
    // Gaze follows the head a little.
    const double look = smooth_noise(key(kLook), t, 1.5);
    set_weight(s, "eyeLookOutLeft", std::max(0.0, look) * 0.4);
    set_weight(s, "eyeLookInRight", std::max(0.0, look) * 0.4);
    set_weight(s, "eyeLookInLeft", std::max(0.0, -look) * 0.4);
    set_weight(s, "eyeLookOutRight", std::max(0.0, -look) * 0.4);
    // Light: a key light above and to one side of the camera, drifting, with ambient fill.
    const double az = 0.6 * smooth_noise(key(kLightAzimuth), t, 6.0) - 0.3;
    const double el = 0.5 + 0.15 * smooth_noise(key(kLightElevation), t, 7.0);
    s.light.direction = Eigen::Vector3f(static_cast<float>(std::sin(az) * std::cos(el)), static_cast<float>(-std::sin(el)),
                                        static_cast<float>(-std::cos(az) * std::cos(el)))
                            .normalized();
    s.light.intensity = static_cast<float>(0.8 + 0.12 * smooth_noise(key(kLightIntensity), t, 5.0));
    s.light.ambient = static_cast<float>(0.42 + 0.06 * smooth_noise(key(kLightAmbient), t, 5.0));
    const double tint = 0.04 * smooth_noise(key(kLightTint), t, 8.0);
    s.light.color = Eigen::Vector3f(static_cast<float>(1 + tint), 1.0f, static_cast<float>(1 - tint));
    if (frame_t < calibration_turn_s) {
      // The paper's control sequence (Sec. 6.3): the actor at rest, facing the camera, turns
      // the head to one side, to the other and back with a slight nod (the first 80 % of the
      // turn), then eases into the performance's first pose, under that pose's light. Blinks go
      // on (they are involuntary); everything else is at rest.
      const double u = frame_t / calibration_turn_s;
      s.expression.setZero();
      set_weight(s, "eyeBlinkLeft", blink);
      set_weight(s, "eyeBlinkRight", blink);
      if (u < kCalibrationTurnShare) {
        const double phase = 2 * M_PI * u / kCalibrationTurnShare;
        s.head_deg = Eigen::Vector3f(static_cast<float>(kCalibrationTurnPitchDeg * std::sin(2 * phase)),
                                     static_cast<float>(kCalibrationTurnYawDeg * std::sin(phase)), 0.0f);
      } else {
        s.head_deg *= static_cast<float>(smoothstep01((u - kCalibrationTurnShare) / (1 - kCalibrationTurnShare)));
      }
    }
    keys.push_back(std::move(k));
  }
  return Timeline(std::move(keys));
}

}  // namespace face_reenact::capture
