#pragma once
// Blinks and winks on frames without depth, from the detector's eye points.
//
// The colour lid reader (gaze.h, GazeOptions::read_lids) needs a fit that places the eyes within
// a pixel or two, which only depth gives: on RGB-only frames an eye the fit misplaces looks shut
// (docs/tracker.md, "Lids"). dlib's six points per eye do follow a closing lid on real video
// (liveportrait_d14: their aspect ratio is 0.35-0.42 open and 0.06-0.11 closed), so on those
// frames the eyeBlink weights are read from that ratio instead (Soukupova and Cech's eye aspect
// ratio: the two lid-to-lid distances over twice the corner-to-corner one), per eye, against
// the actor's own open eye: a high percentile of the ratio over the last frames, learned as the
// video plays (eyes differ between people and with the head's turn; most frames show them open).
// The fraction of the open eye that is left is then turned into the eyeBlink weight whose render
// leaves that fraction: the model's lids do not close linearly in the weight (its eye points
// are shut from about 0.8), so the weight comes from the model's own opening curve.
#include <array>
#include <deque>
#include <string>
#include <vector>

#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker {

struct EyeOpennessOptions {
  bool enabled = true;
  // The actor's open eye: this percentile of the ratio over the last history_frames frames
  // with the eye's points (people blink about every 3-4 s for 0.1-0.3 s, so ~95 % of the frames
  // show the eye open; a long closure still leaves the 80th percentile open after 5 s).
  int history_frames = 150;
  double open_percentile = 0.8;
  // Until this many frames were seen no reading: the open eye is not known yet.
  int min_history = 10;
  // What the detector's points say of the opening: fully open at (1 - dead_zone) x the open
  // ratio and above (the ratio's noise on an open eye, and a narrower look down, read nothing),
  // shut at closed_ratio x the open ratio and below (dlib's lids never meet: 0.06-0.11 of
  // 0.35-0.42 on liveportrait_d14), linear between.
  double dead_zone = 0.15;
  double closed_ratio = 0.3;
  // The six points of an eye must have at least this confidence (pose pruning lowers a turned
  // away eye's; a half-hidden eye's ratio says nothing about its lid).
  float min_confidence = 0.3f;

  bool IsValid(std::string* why) const;
};

// The ratio of one eye's six iBUG points in order (corner, two upper lid, corner, two lower
// lid): (|p1 - p5| + |p2 - p4|) / (2 |p0 - p3|); NaN when the corners coincide. With `down` (a
// unit vector from the brows towards the mouth) the lid distances are measured along it and
// never below 0: lids drawn past each other (the model's eyeBlink at 1 overshoots) read shut,
// not open again.
double EyeAspectRatio(const std::array<Eigen::Vector2f, 6>& points, const Eigen::Vector2f* down = nullptr);

struct EyeOpennessReading {
  bool ok = false;
  std::string message;                  // why there is no reading (ok false)
  std::array<float, 2> blink{};         // eyeBlinkLeft, eyeBlinkRight (the person's left, right)
  std::array<double, 2> ratio{};        // this frame's aspect ratio per eye (same order)
  std::array<double, 2> open_ratio{};   // the open eye it was compared with
};

// The model's eye opening against its eyeBlink weight: the ratio of the bound eye points
// (iBUG 36-47) on the mean face seen from the front, as a fraction of the open eye's, at
// weights 0, 1/n, ..., 1 (made non-increasing). Empty when the model has no eyeBlink blendshapes
// or no eye points.
struct EyeOpeningCurve {
  std::array<std::vector<double>, 2> fraction;  // eyeBlinkLeft, eyeBlinkRight
  bool empty() const { return fraction[0].empty() || fraction[1].empty(); }
  static EyeOpeningCurve FromModel(const TrackerModel& model, int steps = 40);
  // The smallest weight whose opening is `opening` (a fraction of the open eye), linear between
  // the samples; 1 - opening without a curve.
  float WeightFor(int eye, double opening) const;
};

class EyeOpennessReader {
 public:
  // With `model`, weights follow its opening curve (EyeOpeningCurve); without, 1 - opening.
  explicit EyeOpennessReader(const EyeOpennessOptions& options = {}, const TrackerModel* model = nullptr);

  // Reads the frame's eye points (both eyes need them) and adds them to the history. Frames
  // without the points give no reading and leave the history as it is.
  EyeOpennessReading Read(const InputFrame& frame);
  // A new person (or a new track): the open eye is learned again.
  void Reset();
  // Writes a reading's weights into `delta`'s eyeBlinkLeft / eyeBlinkRight entries (those the
  // vector has).
  void WriteBlink(const EyeOpennessReading& reading, Eigen::VectorXf* delta) const;

  const EyeOpennessOptions& options() const { return options_; }

 private:
  EyeOpennessOptions options_;
  EyeOpeningCurve curve_;
  std::array<int, 2> blink_index_;  // eyeBlinkLeft, eyeBlinkRight in the expression vector
  std::array<std::deque<double>, 2> history_;
};

}  // namespace face_reenact::tracker
