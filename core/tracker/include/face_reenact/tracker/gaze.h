#pragma once
// Gaze and lids: the eyeLook* and eyeBlink* blendshape weights read from the colour image around
// the eyes (the lids: GazeOptions::read_lids, below).
//
// The solver cannot read gaze. Turning an eyeball moves its iris across the sphere but not the
// sphere itself, so the depth terms do not see it, and the colour term's Jacobian holds the
// rasterised correspondences fixed within a Gauss-Newton step (energy.h): the iris moving under
// a pixel has no derivative there. At the tracking levels the iris is also 1-2 pixels wide. On
// synthetic actors that look aside, gaze was most of the expression error left
// (docs/tracker.md, "Gaze").
//
// What is used instead is that a turned eyeball is the same sphere: one render of the fitted
// face at full resolution, around the eyes, says which pixels show eyeball and where on the
// sphere each one lies, and the shading of each pixel is fixed; only the albedo under a pixel
// depends on the gaze. The model's eyeball albedo is a pattern around the eye's axis (pupil,
// iris, sclera: docs/face-model.md), so the predicted colour of every eyeball pixel for a
// candidate gaze is the albedo at that pixel's angle from the turned axis times its shading
// (and a brightness gain per eye: the light fitted to the whole face can be off around the eyes).
// Pixels that look like the lids around the eye rather than any part of an eyeball are left out:
// the fit may show an eye more open than it is.
// The axis moves with the eyeLook weights exactly as the model moves the front of the eyeball
// (the blendshapes are linear offsets), so a reading is in the model's own units. Both eyes
// turn together (conjugate gaze: looking to the person's left is eyeLookOutLeft and
// eyeLookInRight); the weights that minimise the colour difference over both eyes, searched on
// a grid and refined, are the reading.
#include <Eigen/Core>
#include <array>
#include <memory>
#include <string>
#include <vector>

#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker {

struct GazeOptions {
  bool enabled = true;
  // Fewer visible eyeball pixels than this over both eyes (closed eyes, a face far away or
  // turned so far that one eye is hidden and the other small): no reading; the solve's weights
  // stay.
  int min_eye_pixels = 12;
  // Pixels the fit shows as eyeball but the image as lid (nearer the lid's colour than any of
  // the eyeball's) are left out; when fewer than this fraction of the fit's eyeball pixels
  // remain, the eyes are mostly covered (a blink the fit does not show) and there is no reading.
  double min_open_fraction = 0.6;
  // Up and down (eyeLookUp*/Down*). Off by default: a turn up or down moves the iris half as far
  // as one to the side, the lids hide most of it, and on sensor-modelled synthetic recordings it
  // read 0.4-0.5 down on an actor 0.65 m away looking straight sideways (and dragged the sideways
  // reading from 0.5 to 0.27). On clean renders it reads within 0.1 (down) and 0.25 (up: the
  // upper lid covers the iris) at 0.6 m.
  bool read_vertical = false;
  // With read_vertical, only when an eye's rendered opening spans at least this many pixel rows;
  // below, the vertical gaze stays 0 (1 m from a 640x480 camera the openings are 3-4 rows).
  int min_vertical_rows = 6;
  // The search: a grid of this many steps over [-1, 1] per axis (horizontal, vertical), then a
  // finer grid around the best cell.
  int grid_steps = 21;
  int refine_steps = 11;
  // Quadratic pull towards looking straight ahead, in the units of the mean squared colour
  // difference (linear RGB): it decides between gazes the image cannot tell apart (an iris
  // half under the lid) and costs 0.0002 at a full turn. 0.0006 read the same on two synthetic
  // recordings (expression error within 0.0003).
  double prior = 0.0002;
  // A reading counts only when it lowers the colour difference of looking straight ahead by at
  // least this fraction of its own: a gaze the image shows clearly does (0.3-1.3 on an actor
  // looking aside by 0.4-0.5, up to 7 by 0.7), while an eye region the fit does not match (an
  // actor pulling faces, squinting and widening the eyes at 320x240) read false gazes of 0.3-0.6
  // at 0.02-0.44. Without a reading the solve's weights stay (it reads no gaze: about 0).
  double min_improvement = 0.3;
  // Eyes that do not turn together (crossed, or turned out): after the conjugate reading each
  // eye's sideways turn is searched on its own, and the two are kept when they lie on opposite
  // sides, differ by at least min_vergence, one of them lowers its own colour difference at the
  // conjugate reading by at least vergence_improvement of it, and neither eye is closed by more
  // than max_blink_for_vergence. An actor crossing her eyes (liveportrait_d6, frames 102-116) read
  // a full turn to one side for both eyes, since one eye matched it; her own turns lower the
  // difference by 0.46-0.77 of it. Each eye on its own, not the two together: an eye turned
  // further than the model turns it keeps most of its difference at any reading, and in the sum
  // it hid the other eye's (d6 crossing one eye while the other looks ahead, frames 7-13: that
  // eye's difference halved, the two together 0.2 lower; read as both eyes turned hard aside). A
  // conjugate gaze's two eyes agree within the readings' scatter (0.1-0.2).
  bool read_vergence = true;
  double min_vergence = 0.3;
  double vergence_improvement = 0.3;
  double max_blink_for_vergence = 0.3;

  // The lids (eyeBlinkLeft/Right), read before the gaze. The solve does not read a blink either:
  // without the eye landmarks (EnergyOptions::all_inner_landmarks, off for dlib, whose eye points
  // do not follow a closing lid) nothing in its energy sees the lid cover the eyeball at the
  // tracking levels. They are read where the fit's opening shows lid: when fewer than
  // lids_below_open_fraction of an eye's rendered eyeball pixels look like an eyeball, or the
  // fit already has an eye closed by more than lids_from_weight. Then the eyes are rendered open,
  // each pixel of the opening is marked eyeball or lid by its colour (as the gaze leaves lid
  // pixels out), and each eye's weight is the one whose rendered opening agrees best with those
  // marks, over lid_steps weights in [0, 1] and refined between them. Frames with open eyes
  // (0.93-0.97 of the pixels look like eyeball on the synthetic actors) cost nothing more.
  // Only on fits with depth and a calibrated identity: without depth (a webcam, a video file)
  // the fit around the eyes is looser, and an eye the fit misplaces looks shut (seed 303 tracked
  // as a video: 2D alignment 4.5 px against 0.7 with depth, and its open eyes read 0.5-1.0 on
  // most frames); the mean face before the calibration misplaced them as badly.
  bool read_lids = true;
  double lids_below_open_fraction = 0.85;
  double lids_from_weight = 0.1;
  int lid_steps = 6;

  // The model's iris reaches about 33 degrees from the eye's axis, half as wide again as a real
  // one; on a real eye looking nearly ahead its best match can be the model's iris turned into a
  // corner. A sideways reading of at least real_iris_check_above is read again with an iris of a
  // real size (11.7 mm across, scaled by the eye distance) and replaced by that reading when the
  // two differ by more than real_iris_disagreement (renders of the model read 0.5 as 0.5 and 0.71:
  // they keep the model's); and where the model's reading is not clear (min_improvement), a
  // glance of at least real_iris_check_above with the real iris, clear by the same gate and with
  // the eyes turned together (read_vergence's test), is taken. On liveportrait_d14's 48
  // hand-judged frames the mean error went 0.226 -> 0.070, frames off by more than 0.5 10 -> 0
  // (docs/tracker.md, "Gaze").
  // Wherever such a reading is taken, each eye is also read on its own with the real iris
  // (read_vergence's search and test), and eyes crossed with each turned in by at least
  // real_iris_crossed_min_turn are taken as crossed: the conjugate reading read an actor crossing
  // her eyes (liveportrait_d6, 78-82 and 244-250) as a hard glance to one side, or not at all.
  // Only crossed: the one reading of eyes turned apart this found on the shared clips was a
  // glance through glasses' glare (liveportrait_d12, frame 88). And each eye turned in clearly: a
  // glance with one eye read at 0.06 passed read_vergence's test (liveportrait_d0, frame 41).
  bool real_iris_check = true;
  double real_iris_check_above = 0.5;
  double real_iris_disagreement = 0.3;
  double real_iris_crossed_min_turn = 0.2;

  // Threads for rendering the eye region (the model's evaluation, the set-up of its triangles)
  // and for costing the searches' candidates (0 = one per hardware thread, at most 8). The
  // reading does not depend on it.
  int threads = 0;

  bool IsValid(std::string* why) const;
};

struct GazeReading {
  bool ok = false;
  std::string message;    // why there is no reading (ok false)
  float horizontal = 0;   // > 0: towards the person's left (eyeLookOutLeft + eyeLookInRight)
  float vertical = 0;     // > 0: up (eyeLookUp*); 0 when not read
  // GazeOptions::read_vergence: the eyes turned apart (crossed or diverging). Then `per_eye` is
  // each eye's sideways reading (the person's left eye first; > 0 towards the person's left, as
  // `horizontal`) and those are the weights written; `horizontal` stays the conjugate reading.
  bool vergence_read = false;
  std::array<float, 2> per_eye{};
  bool vertical_read = false;  // read_vertical, and the opening was tall enough (min_vertical_rows)
  bool real_iris = false;      // the reading is the real-sized iris' (GazeOptions::real_iris_check)
  int pixels = 0;         // eyeball pixels compared
  int eyeball_pixels = 0; // eyeball pixels of the fit's render (pixels: those that look like one)
  double energy = 0;      // mean squared colour difference at the reading, prior included
  double straight_energy = 0;  // the same looking straight ahead
  // The lids (GazeOptions::read_lids): read when lids_read, and then already written into the
  // fit's eyeBlink weights whether or not a gaze was read. lids_message says why they were not
  // read when they were looked at (empty: not needed, the fit's opening showed open eyes).
  bool lids_read = false;
  std::array<float, 2> blink{};           // eyeBlinkLeft, eyeBlinkRight read
  std::array<double, 2> open_fraction{};  // per eye: the open render's eyeball pixels that look like one
  std::string lids_message;
  double ms = 0;          // wall time of the reading
};

class GazeEstimator {
 public:
  // A model without two eyeballs or without the eight eyeLook blendshapes (a test mesh) gives an
  // estimator that is not available() and reads nothing.
  explicit GazeEstimator(const TrackerModel& model);

  bool available() const { return available_; }

  // Reads the gaze of the face fitted as `params` in `frame` (full resolution, linear colour,
  // the frame's camera) and writes it into params->delta's eyeLook weights; the lids, where read,
  // into its eyeBlink weights. Without a gaze reading (ok false) the eyeLook weights are left
  // unchanged. `lids_fit`: the fit places the eyes well enough for the lids (it used the
  // frame's depth and the actor's calibrated identity; FaceTracker says so); the lids are read
  // only then (GazeOptions::read_lids) and on frames with depth. Never throws for frame content.
  GazeReading Read(const gpu::CpuRenderer& renderer, const InputFrame& frame, gpu::FaceParameters* params,
                   const GazeOptions& options, bool lids_fit = true) const;

  // The eyeLook weights (model's expression indices, ARKit order) for a conjugate gaze.
  struct Weight {
    int index = -1;
    float value = 0;
  };
  std::array<Weight, 8> WeightsFor(float horizontal, float vertical) const;
  // The same with each eye's own sideways turn (left eye, right eye; same sign convention).
  std::array<Weight, 8> WeightsForEyes(float left, float right, float vertical) const;

 private:
  struct Eye {
    std::vector<int> vertices;  // the eyeball's vertices
    std::vector<int> front;     // those within 20 degrees of the model's +z from its centre
    int part = 0;               // FacePart value
    // How each eyeLook weight (Out, In, Up, Down) moves the centroids of the vertices and of the
    // front: the blendshapes turn the eyeball about a point behind its centre (the centroid
    // moves 1.6 mm per unit weight, the front 5.4 mm), so the centre moves too; as a turn about
    // the centre alone, gaze read 1.6 times too far.
    std::array<Eigen::Vector3d, 4> centre_per_weight{}, front_per_weight{};
  };
  struct EyeRegion;
  struct Pass {
    bool ok = false;
    std::string message;
    double h = 0, v = 0, energy = 0, straight_energy = 0;
    bool vergent = false;            // the eyes read apart (GazeOptions::read_vergence)
    std::array<double, 2> per_eye{};  // then each eye's sideways reading
    int pixels = 0, rendered_pixels = 0;
    int opening_rows = 0;  // the taller eye's rendered opening, pixel rows
    bool vertical_read = false;
    std::array<double, 2> open_fraction{};  // per eye: its rendered eyeball pixels that look like one
    std::shared_ptr<const EyeRegion> region;  // the render it read (another search of it may reuse it)
  };
  struct EyeState;
  EyeRegion RenderEyeRegion(const gpu::CpuRenderer& renderer, const InputFrame& frame,
                            const gpu::FaceParameters& at, int threads) const;
  // iris_degrees: 0, the model's own albedo pattern around the axis; > 0, an iris of that angular
  // radius: the eyeball's darker vertex colours (pupil and iris) within it, the brighter (sclera)
  // beyond, and a pixel nearest a colour between the two (a blurred iris edge) counts as eyeball.
  std::string ReadEye(const EyeRegion& region, const InputFrame& frame, const gpu::FaceParameters& at, int e,
                      double iris_degrees, EyeState* out, int* opening_rows) const;
  // `rendered`: the render of `fit` with the gaze (h0, v0) when another search made it already.
  Pass Search(const gpu::CpuRenderer& renderer, const InputFrame& frame, const gpu::FaceParameters& fit, float h0,
              float v0, double ch, double cv, double half, const GazeOptions& options, double iris_degrees,
              std::shared_ptr<const EyeRegion> rendered = nullptr) const;
  // The lids (eyeBlink weights) read into `reading`; false when they cannot be read.
  bool ReadLids(const gpu::CpuRenderer& renderer, const InputFrame& frame, const gpu::FaceParameters& fit,
                const GazeOptions& options, GazeReading* reading) const;

  bool available_ = false;
  std::array<Eye, 2> eyes_{};  // left (the person's), right
  // eyeLook indices: [eye][0 = Out, 1 = In, 2 = Up, 3 = Down]
  std::array<std::array<int, 4>, 2> look_{};
  std::array<int, 2> blink_{-1, -1};  // eyeBlinkLeft, eyeBlinkRight (-1: the model has none)
  struct LidVertex {
    int vertex = 0;
    Eigen::Vector3f offset = Eigen::Vector3f::Zero();  // per unit weight of both eyeBlink weights
  };
  std::vector<LidVertex> lid_vertices_;
  const TrackerModel* model_ = nullptr;
  // A real iris (11.7 mm across in a face whose eyes are 63 mm apart) on the mean face's
  // eyeball, degrees from its axis: about 20 on the built model, whose own iris reaches about 33.
  double real_iris_degrees_ = 0;
};

}  // namespace face_reenact::tracker
