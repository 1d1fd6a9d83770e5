#pragma once
// Landmarks on video: the whole frame is searched only on the first frame, after a loss and
// (in a band around the face) every redetect_interval frames; otherwise the shape predictor
// starts from the previous frame's landmarks, re-centred, which keeps the per-frame cost to a
// few shape-predictor runs (the paper's preprocessing budget is about 6 ms per frame).
#include <cstdint>
#include <string>

#include "face_reenact/landmarks/landmark_detector.h"
#include "face_reenact/landmarks/smoothing.h"

namespace face_reenact::landmarks {

struct TrackerOptions {
  DetectorOptions detector = [] {
    DetectorOptions d;
    d.confidence_samples = 3;  // per-frame budget: 3 predictor runs of ~1.2 ms
    // A full search that finds nothing at the frame's resolution retries upsampled 2x, but only
    // while the upsampled frame stays within 640x480: small frames (320x240 webcams and
    // recordings, whose faces are near the HOG detector's ~80 px minimum) get the retry, a
    // 640x480 or larger frame is never upsampled (a 1280x960 search costs ~4x).
    d.max_upsample = 1;
    d.max_search_pixels = 640 * 480;
    return d;
  }();
  // Search the whole frame every frame (no tracking): the reference mode.
  bool detect_every_frame = false;
  // Frames between band re-detections around the tracked face (0: never).
  int redetect_interval = 30;
  // The band: the tracked box grown by this fraction of its size on every side.
  float redetect_band = 0.6f;
  // The start box follows the previous points only when it moves or scales by more than this
  // fraction of its size: a still face then keeps an identical start, and the predictor's
  // output does not pick up noise fed back through the box.
  float start_box_deadband = 0.03f;
  // A tracked fit whose mean confidence falls below this is a lost track.
  float min_track_confidence = 0.25f;
  // After losing the followed face, only a face overlapping its last box is taken for this
  // many frames (it may come back after a blur or a turn); then the largest face is.
  int reacquire_frames = 15;
  // A face that is followed from the first frame on may be the wrong one: someone small in the
  // background found while the person in front was turned away (multi_face.avi: the HOG
  // detector misses a face turned ~30 deg). While the followed face is narrower than
  // prominent_face_max_width of the frame, the whole frame is searched every
  // prominent_face_interval frames, and a face elsewhere (no overlap) whose box has at least
  // prominent_face_area_ratio times the followed one's area becomes the followed face
  // (LandmarkResult::switched_face). A face that fills a fifth of the frame width is the
  // person at the camera: no search then, so a typical webcam user pays nothing.
  int prominent_face_interval = 30;  // 0: never switch to a more prominent face
  float prominent_face_max_width = 0.2f;
  float prominent_face_area_ratio = 2.f;
  SmoothingOptions smoothing;

  bool IsValid(std::string* error) const;
};

// What the tracker did so far (why searches happened, how often the face was lost).
struct TrackerSummary {
  int64_t frames = 0;
  int64_t frames_with_landmarks = 0;
  int64_t full_searches = 0;        // whole-frame HOG searches
  int64_t band_searches = 0;        // periodic searches around the tracked face
  int64_t band_misses = 0;          // band searches that found no face
  int64_t tracked_frames = 0;       // frames fitted from the previous landmarks
  int64_t losses = 0;               // tracks dropped (implausible shape, low confidence, left frame)
  int64_t prominent_searches = 0;   // whole-frame searches for a more prominent face
  int64_t face_switches = 0;        // ... that found one and followed it instead
  std::string last_loss_reason;

  std::string BriefReport() const;
};

class LandmarkTracker {
 public:
  explicit LandmarkTracker(const TrackerOptions& options = {});
  ~LandmarkTracker();
  LandmarkTracker(LandmarkTracker&&) noexcept;
  LandmarkTracker& operator=(LandmarkTracker&&) noexcept;

  // One frame. `timestamp_s` drives the smoothing filter (must increase); `pose` is the
  // tracked head pose of the previous frame, if any, for pose pruning.
  LandmarkResult Track(const ImageView& frame, double timestamp_s, const HeadPose* pose = nullptr);
  // Forget the face (next frame is searched from scratch).
  void Reset();

  bool tracking() const;
  const TrackerSummary& summary() const;
  const TrackerOptions& options() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace face_reenact::landmarks
