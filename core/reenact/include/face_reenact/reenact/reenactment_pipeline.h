#pragma once
// The live reenactment pipeline (paper Sec. 7): one call per target frame tracks the target
// actor, transfers the source actor's expression onto it (Eq. 15), re-renders the target's face
// with the transferred expression under the target's own pose and lighting, fills an opened
// mouth with teeth, tongue and a dark cavity, and composites the result into the target frame
// with a Laplacian-pyramid blend (Sec. 7.4.2). docs/reenactment.md is the spec.
//
// This header is the contract for the live front-ends (OBS source, virtual webcam) and the
// `face-reenact reenact` / `demo` commands. It only grows (new fields get defaults, new
// functions are added); nothing here is removed or changes meaning.
//
// Threading: a ReenactmentPipeline is driven by ONE thread (Process, options, status), or by two
// that split each frame: Track() on one, Render() on the other, so that the next frame's Track
// runs while this frame's Render does (the live session; each half still runs on one thread at a
// time, in frame order). RequestCalibration() alone may be called from any thread at any time (an
// atomic flag that the next Process() or Track() call consumes).
#include <array>
#include <atomic>
#include <chrono>
#include <memory>
#include <optional>
#include <string>

#include <opencv2/core.hpp>

#include "face_reenact/capture/recording.h"
#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/reenact/albedo_texture.h"
#include "face_reenact/reenact/detail_transfer.h"
#include "face_reenact/reenact/mouth_interior.h"
#include "face_reenact/reenact/teeth_texture.h"
#include "face_reenact/reenact/virtual_mirror.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/rgbd_input.h"

namespace face_reenact {
struct FaceModel;
namespace stream {
struct RemoteExpression;
}
}  // namespace face_reenact

namespace face_reenact::reenact {

// The model's expression basis is the 52 ARKit blendshapes in ARKit order
// (arkit_blendshape_names()); the UDP stream uses the same order.
inline constexpr int kNumExpressionWeights = 52;

// What the source side contributes to one target frame: the source actor's expression.
//
// Eq. 15 in blendshape space: delta_out = delta_T,neutral + blend_weight * (delta_S - delta_S,neutral),
// clamped to [0, 1] per weight. With neutral_subtracted, `weights` already is
// (delta_S - delta_S,neutral) (the UDP stream's RemoteExpression carries that) and `neutral` is
// ignored. blend_weight is the stream's cross-fade weight (RemoteExpression::weight): 1 = the
// source's expression, 0 = the target's own tracked expression; in between, the output is
// blend_weight * transferred + (1 - blend_weight) * target's own expression.
struct SourceExpression {
  std::array<float, kNumExpressionWeights> weights{};  // ARKit weights (absolute, or relative)
  std::array<float, kNumExpressionWeights> neutral{};  // the source actor's neutral expression
  bool neutral_subtracted = false;
  float blend_weight = 1.0f;  // in [0, 1]
  // The source frame and its fit, where the source actor is tracked on this machine (a
  // recording, a camera): its folds and wrinkles are carried onto the target (Sec. 7.3,
  // detail_transfer.h). Null over the UDP stream, which carries expressions only.
  std::shared_ptr<const SourceView> view;

  // Values finite, blend_weight in [0, 1]; absolute weights within [-0.5, 1.5] and relative ones
  // within [-1.5, 1.5] (trackers overshoot a little; the transfer clamps).
  bool IsValid(std::string* why) const;
  // delta_S - delta_S,neutral.
  std::array<float, kNumExpressionWeights> relative() const;
};

// A source actor's tracked parameters and calibrated neutral (FaceTracker::neutral(): identity
// and albedo of the actor with the neutral expression) as a SourceExpression (blend_weight 1).
// Missing trailing coefficients of either delta count as 0.
SourceExpression SourceFromParameters(const gpu::FaceParameters& tracked, const gpu::FaceParameters& neutral);
// The same from a source FaceTracker's frame; blend_weight 0 (the target keeps its own
// expression) when the frame has no trustworthy fit (tracking_status_has_fit false).
SourceExpression SourceFromTrackedFrame(const tracker::TrackedFrame& tracked, const gpu::FaceParameters& neutral);
// The receiver's sample (core/stream/.../stream_state.h): relative weights, its cross-fade weight.
// A sample without a frame (has_frame == false) gives blend_weight 0.
SourceExpression SourceFromRemote(const stream::RemoteExpression& remote);

enum class ReenactMode {
  kReenact,      // the source's expression on the target (Eq. 15)
  kPassThrough,  // the target re-rendered with its own tracked expression (checks the pipeline)
  kOff,          // the input frame unchanged (tracking still runs, for status)
  kOverlay,      // the input with the fit drawn over it (fit_overlay.h): is the tracking right?
  kMirror,       // the virtual mirror (virtual_mirror.h): the target's own face re-textured / re-lit
};
const char* reenact_mode_name(ReenactMode mode);

enum class RendererKind {
  kCpu,     // gpu::CpuRenderer (measured faster than lavapipe at small sizes, no device needed)
  kVulkan,  // gpu::Renderer on the default Vulkan device (falls back to kCpu if none opens)
};

// Where the colour of the re-rendered face comes from (docs/reenactment.md, "Appearance").
enum class Appearance {
  // Each surface point takes the target frame's own colour where the frame shows that point (at
  // the target's tracked geometry), times the change of its shading (the new normal against the
  // tracked one): the paper's albedo texture made from the camera image divided by the
  // estimated lighting (Sec. 6.3), refreshed every frame. Skin detail, brows, lips and the
  // camera's grain stay the target's, and the face moves only where the expression moves it.
  // Surface the frame does not show (the inside of lips an opened mouth reveals, a cheek a turn
  // brings into view) takes the per-vertex AlbedoMap.
  kFrameTexture,
  // The per-vertex AlbedoMap everywhere: smooth, holds no detail finer than the mesh.
  kAlbedoMap,
};
const char* appearance_name(Appearance appearance);

struct ReenactmentOptions {
  ReenactMode mode = ReenactMode::kReenact;
  RendererKind renderer = RendererKind::kCpu;
  Appearance appearance = Appearance::kFrameTexture;

  // --- mouth (Sec. 7.3; teeth and tongue from the model's helper geometry) ---
  bool render_mouth = true;
  // The mouth interior (teeth, tongue, dark cavity) is drawn whenever the rendered jawOpen
  // exceeds this: the re-rendered face covers the target's own mouth, so an opened mouth never
  // shows the target's closed lips.
  float mouth_open_threshold = 0.02f;
  // The target actor's own open mouth (Sec. 7.4.1, mouth_interior.h): a still of its teeth,
  // tongue and cavity from one of its tracked frames, warped into every opened mouth in place of
  // the model's teeth and a dark cavity. mouth_exemplar_frame -1 takes the first frame that
  // opens the mouth wide enough while facing the camera (mouth_exemplar_options) and a later one
  // that opens it clearly wider; N >= 0 takes the frame with that index (a recording may name
  // the frame where the actor opened the mouth) and no other. Until there is one, and with
  // mouth_exemplar false, the model's teeth and the dark cavity (PipelineSummary::mouth_interior
  // says which).
  bool mouth_exemplar = true;
  int64_t mouth_exemplar_frame = -1;
  MouthExemplarOptions mouth_exemplar_options;
  // Until the target has opened its own mouth, where the source actor's frame is here (a
  // recording, a camera on this machine: SourceExpression::view; never over the UDP stream): the
  // source's own mouth of that frame, warped into the output's opening as the target's still is,
  // its colours carried from the source's light and camera into the target's by the skin around
  // both mouths (FaceCompositor::ViewMouth). The output's opening has the source's shape,
  // so its teeth and tongue fit it; a target that never opens its mouth (a photo, a speaker who
  // keeps it shut) otherwise shows the model's teeth. Off: the model's teeth meanwhile. Needs
  // mouth_exemplar (and a frame named by mouth_exemplar_frame does not stop it before that frame).
  bool source_mouth = true;
  // The texture laid over the model's teeth wherever they are drawn (teeth_texture.h): the
  // front-ends load the default one built at set-up beside the model (DefaultTeethTexturePath);
  // null: the model's teeth in their flat colour.
  std::shared_ptr<const TeethTexture> teeth_texture;

  // --- frame texture (Appearance::kFrameTexture) ---
  // A frame sample is distrusted near an occluding boundary of the target's own rendering (the
  // lip line, the eyelids, the face's border, a depth jump): across it the frame shows the mouth
  // cavity, teeth, an eyeball, the neck or the background, and a tracking error of a pixel or
  // two puts those colours on the surface. Where the sample moved (the output expression moves
  // the point), or the mouth pass redraws the opening beside it, such pixels fade to the albedo
  // map: the frame's weight is 0 up to half this distance from the boundary (a fit off by 2 px
  // at 640x480 is common) and rises linearly to 1 at this distance. 0 turns the fallback off.
  float frame_texture_boundary_px = 4.0f;

  // --- the actor's albedo texture (Sec. 6.3; albedo_texture.h) ---
  // Built from the target's tracked frames (a front view and one per side where the head turns
  // enough) once the per-vertex map has its first observations, rebuilt when a clearly better
  // view arrives; the re-rendering takes its detail wherever it covers the face. size 0: off.
  AlbedoTextureOptions albedo_texture;

  // --- compositing (Sec. 7.4.2) ---
  int blend_levels = 5;              // Laplacian pyramid levels (>= 1; 1 = plain alpha blend)
  float mask_erosion_px = 1.5f;      // the face mask is eroded by this (at full size) before
                                     // blending, so the rendered silhouette's edge never shows
  float mask_feather_px = 2.0f;      // Gaussian sigma (full size) softening the level-0 mask
  // Only the face skin is re-rendered (not scalp, ears, neck): FacePart::Face triangles.
  bool face_only = true;
  // With target depth: rendered pixels whose input depth lies this much farther (the fit
  // overshoots onto the background) or nearer (something in front of the face) keep the target.
  // 0 turns the check off.
  float depth_background_m = 0.08f;
  float depth_occluder_m = 0.04f;
  // Threads of the CPU re-rendering (model evaluation and rasterisation; 0 = one per hardware
  // thread, at most 8). The output does not depend on it.
  int render_threads = 0;

  // --- wrinkle-level detail (Sec. 7.3; detail_transfer.h): from SourceExpression::view, in
  // ReenactMode::kReenact only ---
  DetailTransferOptions detail;

  // --- the virtual mirror (ReenactMode::kMirror; virtual_mirror.h) ---
  MirrorOptions mirror;

  // --- tracking of the target (core/tracker/.../face_tracker.h, rgbd_input.h) ---
  tracker::TrackerOptions tracker;
  // Landmarks from the dlib tracker (default) or, for synthetic recordings, the stored ones.
  tracker::RgbdInputOptions input;
  // With ground truth in the target frame (synthetic recordings) use it instead of tracking
  // (tests, the closed-loop demo's reference run). Off for every live use.
  bool use_ground_truth_target = false;

  bool IsValid(std::string* why) const;
  // The front-ends' one setting for the three switches above (reenact --mouth, webcam and bench
  // live --mouth, the live session's and the OBS source's "mouth"): "auto" (the target's own
  // open mouth once seen, the source actor's own mouth until then where its frames are here, else
  // the model's teeth), "target" (the target's own only; the model's teeth until then) or
  // "model" (the model's teeth and a dark cavity, always). False for any other name, options
  // unchanged.
  bool SetMouth(const std::string& name);
  // Whether a source frame (SourceExpression::view) is of use to these options: its folds and
  // wrinkles (detail) or its mouth (source_mouth). Front-ends attach the frame only then.
  bool UsesSourceView() const;
};

// Where the target's tracker is, in three states a front-end can show (ReenactedFrame::tracked
// has the tracker's finer status).
enum class TrackingStatus {
  kCalibrating,  // collecting / fitting the calibration frames: output = input
  kTracking,     // the face is tracked (tracker: kCalibrated, kTracking, kRecovered): reenacted
  kLost,         // no face, a failed fit or a bad frame (kLost, kNoFace, kBadInput): output = input
};
const char* tracking_status_name(TrackingStatus status);

// Per-stage wall-clock times of one Process() call, milliseconds.
struct StageTimes {
  double track_ms = 0;      // landmarks + tracker fit (or calibration)
  double transfer_ms = 0;   // Eq. 15
  double render_ms = 0;     // face re-render (model evaluation + rasterisation + shading)
  double mouth_ms = 0;      // teeth/tongue/cavity render
  double composite_ms = 0;  // masks + Laplacian blend + 8-bit conversion
  double total_ms = 0;
  double detail_ms = 0;     // the source's detail: its frame prepared, carried onto the target
};

struct ReenactedFrame {
  int frame_index = 0;        // the input frame's index
  cv::Mat bgr;                // CV_8UC3, the target frame's size; equals the input where nothing was drawn
  TrackingStatus status = TrackingStatus::kLost;
  bool reenacted = false;     // a face was rendered and composited into `bgr`
  bool mouth_drawn = false;   // the mouth interior was drawn
  bool mouth_from_exemplar = false;  // ... from an open-mouth image (mouth_interior.h): the target's still or,
                                     // with mouth_from_source, the source actor's frame
  bool mouth_from_source = false;    // ReenactmentOptions::source_mouth drew the interior
  std::string message;        // why the input was passed through (empty when reenacted)
  gpu::FaceParameters target_params;  // the target's tracked P (meaningful when tracking)
  gpu::FaceParameters output_params;  // P that was rendered (target with the transferred expression)
  cv::Mat face_mask;          // CV_8UC1, 255 where the blend took the rendered face (level-0 mask)
  // The depth that goes with `bgr` (CV_32FC1, metres, 0 = none): the target's depth with the
  // re-rendered face's depth where the face was drawn, no data in the open mouth. Empty when
  // the target frame has no depth. Lets the output be written and re-tracked as an RGB-D frame.
  cv::Mat depth;
  // The re-rendered layers over the target before blending (CV_8UC3; debug views); empty when
  // nothing was rendered.
  cv::Mat rendered;
  StageTimes times;
  // The target tracker's own result for this frame (its finer status, message, energies).
  // Default-constructed when use_ground_truth_target is set.
  tracker::TrackedFrame tracked;
};

// Cumulative statistics since construction.
struct PipelineSummary {
  int frames = 0;
  int reenacted_frames = 0;
  int lost_frames = 0;
  int calibrating_frames = 0;
  StageTimes mean_times;  // mean over all processed frames
  std::string renderer;   // which rasteriser ran: "cpu", "vulkan (<device>)", "cpu (Vulkan unavailable: ...)"
  // Where an opened mouth's interior comes from: "the target's own mouth, frame N (jawOpen J)",
  // or "the model's teeth and a dark cavity: ..." with the reason (ReenactmentOptions::mouth_exemplar),
  // and on how many frames the source actor's mouth stood in (ReenactmentOptions::source_mouth).
  std::string mouth_interior;
  int source_mouth_frames = 0;
  // On how many frames an eye the target held closed (a blink) and the output open was drawn
  // from the target's open eyes (EyeExemplar), and the last frame those were taken from (-1: none yet).
  int eye_exemplar_frames = 0;
  int64_t eye_exemplar_frame = -1;
  // What wrinkle-level detail the output carries (DetailTransfer::Description), and on how many
  // frames it changed the face.
  std::string detail;
  int detail_frames = 0;
  // The albedo texture (ReenactmentOptions::albedo_texture): how often it was built, what the
  // last build took, and its views (frame, yaw, texels seen); empty views: none built.
  int albedo_texture_builds = 0;
  double albedo_texture_ms = 0;  // the last build: the views' unwraps and their blend
  std::vector<AlbedoTexture::ViewInfo> albedo_texture_views;
  std::string albedo_texture_note;  // why there is none, when it is off or failed
  std::string BriefReport() const;
};

// The target's eye openings as its frame shows them: the landmark detector's six points on each
// eye's lid margins (iBUG 36-41 and 42-47, in order around the eye), in the frame's pixels. The
// fit's lids miss the real margins by a pixel or two; where the output turns the gaze or moves the
// lids, the eyeball is drawn within the real opening (moved as the output moves the lids), and the
// frame's lids keep their place around it (Compose).
struct EyeOpenings {
  std::array<std::array<Eigen::Vector2f, 6>, 2> points{};  // [0]: iBUG 36-41, [1]: 42-47
  std::array<bool, 2> known{false, false};                // the detector found all six points of that eye
  bool empty() const { return !known[0] && !known[1]; }
};
// The openings of a frame's detected landmarks (an eye with any of its six points missing or of
// confidence 0 is not known).
EyeOpenings EyeOpeningsFromLandmarks(const std::vector<tracker::InputLandmark>& landmarks);

// A target frame after ReenactmentPipeline::Track: what Render needs to finish it. Plain data,
// moved from one thread to the other.
struct TrackedTarget {
  ReenactedFrame frame;        // the output so far (the input's copy, status, message, tracked fit)
  bool finished = false;       // nothing is left to render: `frame` is the output (Render only books it)
  gpu::PinholeCamera camera;   // the camera the fit is in
  gpu::FaceParameters neutral; // the target's neutral at this frame (Eq. 15)
  bool forget_actor = false;   // a recalibration was requested: the learned appearance starts again
  EyeOpenings eye_openings;    // the detector's lid points of this frame (Compose)
  std::chrono::steady_clock::time_point start;  // Track's start (ReenactedFrame::times.total_ms)
};

// The first part of Track: the target frame checked and copied, its input made (the conversion
// and the landmark detector's points), before any fitting. What Track(PreparedTarget) needs.
struct PreparedTarget {
  TrackedTarget tracked;         // the output's copy of the input; finished when the frame was refused
  tracker::InputFrame input;     // the frame as the tracker reads it, with the detector's landmarks
  tracker::RgbdInputInfo info;   // the conversion's and the detector's times and status
  gpu::PinholeCamera camera;     // the frame's camera
  std::optional<gpu::FaceParameters> ground_truth;  // use_ground_truth_target: the frame's own
  double ms = 0;                 // the preparation's time (part of ReenactedFrame::times.track_ms)
};

class ReenactmentPipeline {
 public:
  // Throws face_reenact::Error on invalid options or model. The model must outlive the pipeline.
  ReenactmentPipeline(const FaceModel& model, const ReenactmentOptions& options);
  ~ReenactmentPipeline();
  ReenactmentPipeline(const ReenactmentPipeline&) = delete;
  ReenactmentPipeline& operator=(const ReenactmentPipeline&) = delete;

  // One target frame. `source` == nullptr (or mode kPassThrough): the target's own expression.
  // Never throws for bad frame content (no face, empty or odd-sized image, NaN depth): the
  // output is then the input (or a black frame for an empty input) with status and message set.
  // Throws face_reenact::Error only on programmer errors (an invalid SourceExpression).
  ReenactedFrame Process(const capture::RgbdFrame& target, const SourceExpression* source);
  // Process in two halves (Process = Render(Track(target), source)): Track validates the frame and
  // tracks the target (landmarks, the fit, the overlay mode's drawing); Render learns the
  // appearance, transfers the expression, re-renders and composites. Render(n) may run on another
  // thread while Track(n+1) runs; the same guarantees as Process.
  TrackedTarget Track(const capture::RgbdFrame& target);
  ReenactedFrame Render(TrackedTarget tracked, const SourceExpression* source);
  // Track in two parts (Track(target) = Track(Prepare(target))): Prepare checks the frame and runs
  // the landmark detector, Track fits. Prepare(n+1) may run on another thread while Track(n) runs
  // (the live session's landmark stage, docs/real-time.md): the detector then starts from the pose
  // of the last frame whose Track had finished, one frame older than one after the other. Each is
  // called from one thread at a time, in frame order, and neither beside SetOptions.
  PreparedTarget Prepare(const capture::RgbdFrame& target);
  TrackedTarget Track(PreparedTarget prepared);

  // Thread-safe: the next Process() restarts the target's calibration (e.g. a new person sat down).
  void RequestCalibration();

  // Changes options between frames (same thread as Process). A change of calibration_frames
  // or use_ground_truth_target takes effect at the next calibration. Throws on invalid options.
  void SetOptions(const ReenactmentOptions& options);
  const ReenactmentOptions& options() const;

  TrackingStatus status() const;
  // The target's calibrated neutral (identity, albedo, neutral expression, last pose and
  // lighting); valid once status() has been kTracking.
  const gpu::FaceParameters& target_neutral() const;
  // Non-empty when the target's last calibration saw a face not at rest
  // (tracker::FaceTracker::calibration_warning()): the front-end should ask for a new one.
  std::string calibration_warning() const;
  // The target's tracker is watching for a relaxed face to calibrate again on
  // (tracker::FaceTracker::watching_for_relaxed_face()).
  bool watching_for_relaxed_face() const;
  // The target's calibration again on its most relaxed frames (FaceTracker::relaxed_recalibration();
  // searched false without a tracker or before one was needed).
  tracker::FaceTracker::RelaxedRecalibration relaxed_recalibration() const;
  // The target tracker's focal length search (tracker::FaceTracker::focal_length_report(); not
  // searched with ground truth or before the first calibration).
  tracker::FaceTracker::FocalLengthReport focal_length_report() const;
  // Where the target's calibration stands (tracker::FaceTracker::calibration_progress(): frames
  // collected, a background solve running); nothing collecting or solving with ground truth.
  tracker::FaceTracker::CalibrationProgress calibration_progress() const;
  // The tracker's solver in words (tracker::FaceTracker::solver_description; "" without a tracker).
  std::string tracking_solver() const;
  // Whether the tracker solves on a GPU (tracker::FaceTracker::solves_on_gpu; false without one).
  bool tracking_solves_on_gpu() const;
  PipelineSummary summary() const;
  // The target's open-mouth still in use (empty: none yet, or mouth_exemplar off).
  const MouthExemplar& mouth_exemplar() const;
  // Whether the albedo texture (ReenactmentOptions::albedo_texture) still lacks a view turned to
  // either side (AlbedoViewChooser): the live status asks the target to turn the head once.
  bool wants_side_views() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::atomic<bool> calibration_requested_{false};
};

}  // namespace face_reenact::reenact
