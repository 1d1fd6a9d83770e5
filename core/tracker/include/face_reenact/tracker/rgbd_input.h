#pragma once
// From recordings and cameras to the tracker's InputFrame: an RGB-D recording frame
// (capture::RgbdFrame: 8-bit BGR colour, depth in metres, camera) becomes linear colour, depth
// and the 68 landmarks of E_lan, taken either from the landmark tracker (core/landmarks) run on
// the colour image or from the landmarks stored with the recording (synthetic ground truth).
//
// Contract header (the reenactment pipeline and the OBS source use it); changes are additive.
#include <memory>
#include <mutex>
#include <string>

#include "face_reenact/capture/recording.h"
#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/landmarks/landmark_detector.h"
#include "face_reenact/landmarks/landmark_tracker.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/input_frame.h"

namespace face_reenact::tracker {

struct RgbdInputOptions {
  LandmarkSourceChoice landmark_source = LandmarkSourceChoice::kDetector;
  // false drops the depth map (RGB-only input: the depth terms then have nothing to act on).
  bool use_depth = true;
  // Stored (recording) landmarks: visible points get this confidence, hidden ones 0.
  float stored_landmark_confidence = 1.0f;
  // Detector landmarks: points the detector marks invisible get confidence 0; the others keep
  // the detector's per-point confidence times this factor.
  float detector_confidence_scale = 1.0f;
  landmarks::TrackerOptions detector;  // used when landmark_source == kDetector

  bool IsValid(std::string* why) const;
};

// What happened while a frame was converted.
struct RgbdInputInfo {
  double landmarks_ms = 0;        // landmark detection/tracking (0 for stored landmarks)
  double conversion_ms = 0;       // colour/depth conversion
  int landmarks = 0;              // landmarks with confidence > 0
  std::string landmark_status;    // "ok", the detector's status and reason, or "no stored landmarks"
  bool depth_used = false;        // the frame carries a depth map
};

// Colour (CV_8UC3 BGR, sRGB) -> linear RGB, depth (CV_32FC1 metres; 0 / NaN / inf = no data,
// kept as such), camera. No landmarks. Throws face_reenact::Error when the frame's images do
// not match its camera (wrong type or size): that is a broken source, not a tracking problem.
// `reuse` (optional): a finished frame whose buffers the new one takes, written over in full (no
// allocation, page faults or zeroing when they already have this frame's size).
InputFrame MakeInputFrameNoLandmarks(const capture::RgbdFrame& frame, bool use_depth, InputFrame* reuse = nullptr);

// Landmarks stored with a recording frame (ground truth): visible points with `confidence`,
// hidden ones with 0. Empty when the frame has none.
std::vector<InputLandmark> StoredLandmarks(const capture::RgbdFrame& frame, float confidence);

// A detector result as E_lan input: confidence * scale for visible points, 0 for the others;
// empty when the result has no landmarks.
std::vector<InputLandmark> DetectedLandmarks(const landmarks::LandmarkResult& result, float scale);

// The head pose of `params` in the landmark code's image-terms convention (yaw > 0 turns the
// nose toward +x, pitch > 0 tilts the chin down, roll > 0 turns the face clockwise), for the
// detector's pose pruning.
landmarks::HeadPose HeadPoseFromParameters(const gpu::FaceParameters& params);

// One-call adapter: `detector` may be null when options.landmark_source == kRecording.
InputFrame MakeInputFrame(const capture::RgbdFrame& frame, const RgbdInputOptions& options,
                          landmarks::LandmarkTracker* detector, RgbdInputInfo* info = nullptr,
                          const landmarks::HeadPose* pose = nullptr, InputFrame* reuse = nullptr);

// Starts reading the landmark model an RgbdInput with `options` will load (kDetector only), in the
// background (landmarks::PreloadShapeModel): a pipeline calls it before its other set-up.
void PreloadLandmarkModel(const RgbdInputOptions& options);

// The adapter with its own landmark tracker (created only for kDetector; creating it loads the
// dlib model and throws face_reenact::Error when that is missing). Feed it the tracker's
// output with SetTrackedPose so the landmark detector can prune far-side points.
class RgbdInput {
 public:
  explicit RgbdInput(const RgbdInputOptions& options);
  ~RgbdInput();
  RgbdInput(RgbdInput&&) noexcept;
  RgbdInput& operator=(RgbdInput&&) noexcept;

  InputFrame Convert(const capture::RgbdFrame& frame, RgbdInputInfo* info = nullptr);
  // Hands back a frame Convert made, once nothing reads it: the next Convert writes into its
  // buffers. Made anew, a 1280x720 frame's colour (11 MB) was faulted in and zeroed page by page
  // before the conversion wrote it, more than the conversion itself. Safe beside a Convert on
  // another thread (the live session's landmark stage).
  void Recycle(InputFrame&& frame);
  // The last tracked fit (only used for kDetector); call with has_fit = false after a loss.
  void SetTrackedPose(const gpu::FaceParameters& params, bool has_fit);
  // Forget the landmark track (a cut in the video).
  void Reset();
  const RgbdInputOptions& options() const { return options_; }

 private:
  RgbdInputOptions options_;
  std::unique_ptr<landmarks::LandmarkTracker> detector_;
  bool have_pose_ = false;
  landmarks::HeadPose pose_;
  std::unique_ptr<std::mutex> spare_mu_ = std::make_unique<std::mutex>();
  InputFrame spare_;  // Recycle's, for the next Convert
};

}  // namespace face_reenact::tracker
