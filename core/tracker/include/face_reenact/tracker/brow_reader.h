#pragma once
// The brows, read from the detector's brow points after each solve.
//
// The paper's 38 landmarks have no brows and the colour barely changes as a brow lifts, so the
// solve never reads the brow blendshapes on RGB video (liveportrait_d14: the tracked browInnerUp
// / browOuterUp stayed flat while the actor raised her brows). Putting the brows into E_lan
// (EnergyOptions::use_brow_landmarks) reads them at a third of their size: the model's brow
// blendshapes move the brow points by only 3-6 mm, and under the tracker's sparsity prior that
// pull is too weak; without the prior a monocular fit still reads them scaled by the fitted
// face's distance (docs/tracker.md, "Brows").
//
// So the brows are read as the lids are on video (eye_openness.h): from the points, in the
// face's own frame and units. For the frame's fit, the model's brow points are projected with the
// brow weights at 0 and with each brow blendshape, and both they and the detector's points are
// expressed relative to the eye corners (origin between the eyes, x along the eye line, unit the
// eye distance), which removes the fitted face's scale and distance and follows the head's turn.
// What the detector's brows do beyond the model's rest brows is an actor's own offset (where dlib
// puts this person's brows against the model's bound vertices: the median over the last frames,
// most of which show the brows at rest) plus the brow motion, whose weights (browInnerUp,
// browOuterUp and browDown, each side on its own) are the bounded least-squares fit of the
// blendshapes' point motions.
#include <array>
#include <deque>
#include <string>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker {

struct BrowReaderOptions {
  bool enabled = true;
  // The actor's offset: the per-coordinate median over the last history_frames frames read
  // (people hold a raised brow for a second or two; most of 5 s shows the brows at rest).
  int history_frames = 150;
  // Until this many frames were seen no reading: the offset is not known yet.
  int min_history = 10;
  // A weight below this reads 0, and the rest is stretched back to [0, 1]: the detector's brow
  // points jitter by about a pixel on a face 100 px across (measured: docs/tracker.md, "Brows").
  double dead_zone = 0.1;
  // Each weight is the median of the last this many readings (1: none). dlib's brow points jump
  // by a few pixels on single frames (liveportrait_d14: browInnerUp through a held raise read
  // 0.20, 1.00, 0.38, 0.00, 0.76, 1.00 on six frames running); a median of 3 removes such a
  // frame and delays a real change by one frame.
  int median_frames = 3;
  // The brow points and the eye corners must have at least this confidence.
  float min_confidence = 0.3f;

  bool IsValid(std::string* why) const;
};

// browInnerUp, browOuterUpLeft, browOuterUpRight, browDownLeft, browDownRight.
inline constexpr int kNumBrowBlendshapes = 5;
const std::array<const char*, kNumBrowBlendshapes>& brow_blendshape_names();

struct BrowReading {
  bool ok = false;
  std::string message;                           // why there is no reading (ok false)
  std::array<float, kNumBrowBlendshapes> weight{};  // in brow_blendshape_names() order
  double residual = 0;  // the points' distance from the read motion, RMS, in eye distances
};

class BrowReader {
 public:
  explicit BrowReader(const TrackerModel& model, const BrowReaderOptions& options = {});

  // Reads the frame's brow points against the fit `params` (pose, identity; its brow weights are
  // ignored) under `camera`, adds them to the history and, with enough history, returns the
  // weights. No reading (and no history) without the points or the model's brow landmarks.
  BrowReading Read(const InputFrame& frame, const gpu::FaceParameters& params, const gpu::PinholeCamera& camera);
  // A new person, a new identity or a new track: the actor's offset is learned again.
  void Reset() {
    history_.clear();
    recent_.clear();
  }
  // Writes a reading's weights into `delta`'s brow entries (those the vector has).
  void Write(const BrowReading& reading, Eigen::VectorXf* delta) const;
  // Sets `delta`'s brow entries to 0: the rest the reader reads against (for a calibrated neutral).
  void ClearBrows(Eigen::VectorXf* delta) const;

  // Whether the model has what the reader needs (the brow and eye-corner landmarks, the brow
  // blendshapes).
  bool usable() const { return usable_; }
  const BrowReaderOptions& options() const { return options_; }

 private:
  static constexpr int kPoints = 10;  // iBUG 17-26
  using Offsets = Eigen::Matrix<double, 2 * kPoints, 1>;
  const TrackerModel* model_;
  BrowReaderOptions options_;
  bool usable_ = false;
  std::array<int, kNumBrowBlendshapes> blendshape_{};
  std::array<int, kPoints> brow_vertex_{};
  std::array<int, 8> reference_vertex_{};  // iBUG 36, 39, 42, 45 (eye corners), 27-30 (nasal bridge)
  std::deque<Offsets> history_;
  std::deque<std::array<double, kNumBrowBlendshapes>> recent_;  // the last readings, for the median
};

}  // namespace face_reenact::tracker
