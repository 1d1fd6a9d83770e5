#pragma once
// The tracking pipeline of Sec. 6.3 / 8.1 of Thies et al. 2015 around the Gauss-Newton solver:
//
//  1. Calibration: the first `calibration_frames` usable frames (a face with enough landmarks)
//     are collected; then identity alpha, albedo beta and, per frame, expression, lighting and
//     pose are optimised jointly over all of them (CpuSolver::SolveFrames, or the solver given to
//     SetCalibrationSolver, with the calibration layout). Identity and albedo are then fixed, and the actor's neutral expression is the
//     mean expression over the calibration frames as tracking reads them (the transfer of Eq. 15
//     subtracts it).
//  2. Tracking: every frame solves expression, lighting and pose (tracking layout), warm-started
//     from the previous frame's result.
//  3. Loss and recovery: a fit is "lost" when the frame has too few landmarks, the landmarks
//     are far from the projected model, the energy jumps far above its recent level, or no
//     pixel carries a residual. The next frame that has landmarks re-initialises the pose from
//     the landmarks alone (a rigid fit of the model's landmark vertices: 3D-3D from depth when
//     the frame has depth there, then a perspective-n-point refinement) and solves from that;
//     the frame is reported kRecovered. The user never has to do anything.
//
// Contract header: the reenactment pipeline and the OBS source code against it; it changes only
// additively. docs/tracker.md describes the behaviour and the measured accuracy.
//
// Thread compatibility: a FaceTracker is thread-compatible (use one from one thread at a time),
// except RequestCalibration(), which may be called from any thread at any time (e.g. the OBS
// "Calibrate" button on the UI thread while the video thread runs Track()). Different
// FaceTracker objects are independent.
#include <atomic>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <stop_token>
#include <string>
#include <vector>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/tracker/brow_reader.h"
#include "face_reenact/tracker/depth_alignment.h"
#include "face_reenact/tracker/energy.h"
#include "face_reenact/tracker/fit_agreement.h"
#include "face_reenact/tracker/focal_length.h"
#include "face_reenact/tracker/eye_openness.h"
#include "face_reenact/tracker/gaze.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/parameter_layout.h"
#include "face_reenact/tracker/plausible_light.h"
#include "face_reenact/tracker/solver.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact {
struct FaceModel;
}

namespace face_reenact::tracker {

// Where the landmarks of E_lan come from when frames are made from recordings (rgbd_input.h).
enum class LandmarkSourceChoice {
  kDetector,   // the landmark detector/tracker (core/landmarks) run on every colour image
  kRecording,  // the landmarks stored with the recording (synthetic ground truth); frames
               // without stored landmarks then have none
};
const char* landmark_source_choice_name(LandmarkSourceChoice choice);

// When a fit counts as lost (all distances in pixels of an image 640 px wide, like E_lan, so the
// thresholds mean the same at any resolution).
struct LossDetectionOptions {
  // Fewer usable landmarks (inner points with confidence > min_landmark_confidence) than this:
  // the frame has no trackable face (kNoFace).
  int min_landmarks = 8;
  float min_landmark_confidence = 0.05f;
  // Mean distance between the input landmarks and the projected model landmark vertices at
  // the warm start above which the pose is re-initialised from the landmarks before solving
  // (a fast head motion or a face re-entering elsewhere).
  double reinit_landmark_error_px = 40.0;
  // Mean landmark distance after the solve above which the fit is lost.
  double lost_landmark_error_px = 20.0;
  // The fit is suspect when the final energy exceeds this multiple of the median of the last
  // `energy_history` tracked frames (and that median is above min_reference_energy): the
  // frame is then re-solved from a landmark re-initialisation, and if that does not help either
  // it is lost.
  double max_energy_ratio = 6.0;
  int energy_history = 15;
  double min_reference_energy = 1e-3;
  // Fewer pixels carrying the dense terms on the finest solved level than this counts as "no
  // valid residuals" (e.g. all-invalid depth where the face should be) for RGB-D input.
  int min_dense_pixels = 30;
  // The fit against the frame's own evidence (fit_agreement.h): its head pose against the
  // landmarks' pose, its inner landmarks against the detector's, its rotation speed. A fit that
  // disagrees is re-solved from a landmark re-initialisation, and lost if that disagrees too; so
  // no frame is reported tracked with its head turned away from the face.
  FitAgreementOptions agreement;

  bool IsValid(std::string* why) const;
};

// Where the joint calibration solve starts each frame's expression (TrackerOptions::
// calibration_start).
enum class CalibrationStart {
  kNeutral,       // all blendshape weights 0: the identity has to explain the shape
  kPerFrameFits,  // the expressions the per-frame fits (mean or previous identity) found
  kLowerEnergy,   // both, keeping the result with the lower final energy (twice the time)
};
const char* calibration_start_name(CalibrationStart start);  // "neutral", "per-frame-fits", ...
// Parses calibration_start_name's words; false for anything else.
bool parse_calibration_start(const std::string& name, CalibrationStart* start);

// The calibration window's choice (TrackerOptions::calibration_window_frames): given the head
// rotations of the frames kept so far and a candidate's, the index of the kept frame the
// candidate should replace, or -1 to keep the set. The set's spread is the sum over its frames
// of the angle to the nearest other frame; the swap that widens it most wins, and only a strict
// gain swaps (so a still head keeps the earliest frames).
int calibration_pose_swap(const std::vector<Eigen::Matrix3f>& kept, const Eigen::Matrix3f& candidate);

// Which solver runs a FaceTracker's Gauss-Newton solves (solver_choice.h): the CPU reference,
// the Vulkan compute solver, or kAuto: Vulkan on a real GPU, the CPU where the only Vulkan
// device is a CPU implementation (lavapipe), on which the CPU solver is the faster.
enum class SolverBackend { kAuto, kCpu, kVulkan };

struct TrackerOptions {
  // The per-frame and calibration solver (solver_choice.h). The CPU by default, so that a tracker
  // made without a front-end opens no device; the programs (track, reenact, the live session
  // behind OBS and the webcam, send --input) ask for kAuto: the fastest solver for the machine.
  SolverBackend solver = SolverBackend::kCpu;
  std::string solver_device;  // Vulkan device selector (gpu::Context); empty: FR_VULKAN_DEVICE or automatic
  // Calibration (Sec. 6.3): jointly over this many usable frames. 1 = the first usable frame.
  int calibration_frames = 5;
  // Usable frames are taken at least this many frames apart (the actor turning the head gives
  // more varied views than consecutive frames).
  int calibration_frame_stride = 1;
  // The paper's calibration sequence is the actor turning the head (Sec. 6.3). A window > 0
  // watches that many usable frames (each tracked with the current identity meanwhile) and keeps
  // the calibration_frames among them with the most varied head poses (calibration_pose_swap),
  // then calibrates; 0 takes the first usable frames calibration_frame_stride apart. Measured
  // on five synthetic actors turning 25 degrees each way at rest (`synth --calibration-turn 2`),
  // a window of 60 over the turn lowered the surface max on all five (5.99 -> 4.66, 20.7 -> 17.2
  // mm) and the 2D error on all five (docs/tracking-pipeline.md, "Calibration over a head turn").
  // It is off by default: it delays the calibration by its length, and a recording shorter than
  // the window never calibrates. Needs calibration_frame_stride 1.
  int calibration_window_frames = 0;
  // Leading identity / albedo components solved during calibration (-1 = all of the model's).
  int calibration_identity_components = -1;
  int calibration_albedo_components = -1;
  // Where the joint solve starts each calibration frame's expression. The fits before
  // calibration use the mean identity, and their expressions absorb the difference between the
  // mean face and the actor (on the demo's target, a closed mouth read jawOpen 1.0; started from
  // there, the actor's neutral held an open jaw, which the transfer of Eq. 15 then subtracted).
  // Identity and expression trade along a valley, so which start fits the surface better depends
  // on the actor, and the lower final energy picks it (kLowerEnergy, measured on five synthetic
  // actors). The default is neutral all the same: the actor is expected at rest while
  // calibrating (Sec. 6.3), and the fits' start, where it wins on energy, brings an identity that
  // explains the face together with an expression offset the neutral then keeps: on the demos
  // where it won, the reenacted jaw followed the source worse (0.29 -> 0.40 and 0.20 -> 0.28 off).
  // docs/tracking-pipeline.md, "Calibration start".
  CalibrationStart calibration_start = CalibrationStart::kNeutral;
  // The actor's neutral expression (neutral(), subtracted by Eq. 15) is the mean over the
  // calibration frames re-fitted by the tracking solve (identity fixed, the tracking prior),
  // not the joint solve's own expressions: the transfer subtracts it from tracked expressions,
  // so it has to be read the same way. The joint solve's weaker quadratic prior read the demo
  // target's closed mouth about 0.06 jawOpen wider than tracking did, and the difference opened
  // the reenacted mouth of a source at rest. Costs one tracking solve per calibration frame.
  bool neutral_from_tracking = true;
  // Calibration assumes the actor at rest (paper Sec. 6.3). When a weight of the calibrated
  // neutral expression exceeds this, the actor was smiling, talking or frowning: part of that
  // expression went into the identity and stays in every reenacted frame, so the tracker says so
  // (calibration_warning(), the calibrated frame's message). Synthetic actors at rest calibrate
  // to at most 0.15; actors holding a smile of 0.8-1.0 to 0.44-0.65
  // (docs/tracking-pipeline.md, "A face not at rest while calibrating"). 0 switches it off.
  float rest_warning_weight = 0.3f;
  // A calibration whose neutral is not at rest is not the last word (paper Sec. 6.3 asks for a
  // relaxed face; a user in front of a webcam is often talking or smiling when it starts): when
  // the neutral's strongest weight (as the warning counts it: not the gaze, not the brows the
  // brow reader reads) exceeds relaxed_recalibration_above, the next
  // relaxed_recalibration_frames tracked frames, fitted with the new identity, are watched for
  // the calibration_frames whose expression is the most relaxed (their strongest weight at least
  // relaxed_margin below the neutral's), and the calibration runs again on them. Its identity is
  // kept only when its neutral is more at rest than the first; the warning then stands only if
  // that is still above rest_warning_weight (no relaxed frame was found). The trigger is below
  // the warning: synthetic actors at rest calibrate to at most 0.15, and a neutral of 0.2-0.3
  // keeps that much expression in every reenacted frame too. Measured on the real clips of
  // ../shared/data/videos (docs/tracking-pipeline.md, "Calibrating again on the most relaxed
  // frames"). 0 frames switch it off. In the background (background_calibration) the frames of
  // its solve are held, as for a requested calibration.
  int relaxed_recalibration_frames = 90;
  float relaxed_recalibration_above = 0.2f;
  float relaxed_margin = 0.05f;
  // The joint solve: more Gauss-Newton iterations than tracking (it starts from the mean face),
  // on the coarsest level only: measured on synthetic recordings, finer levels and more
  // iterations cost 3x the time and fit the identity no better (docs/tracker.md).
  // The identity prior is weaker than while tracking (w_reg 0.005 instead of 0.025): the data
  // terms are averaged over pixels (docs/tracker.md), so the paper's weight holds identity
  // close to the mean face; the weaker prior measured better rotation and surface errors.
  // The expression rows keep the paper's w_reg_expression 0.025 (a weaker expression prior
  // let the per-frame expressions absorb identity: expression error 0.089 against 0.074).
  // No point-to-point term (use_point false; the plane term and the others keep the paper's
  // weights): with projective correspondences its Gauss-Newton steps kept lowering the energy
  // with the correspondences held while the energy after re-rendering climbed (seed 202, 640x480: 1.74
  // at iteration 23 -> 2.42 at 60, the residual count falling 162k -> 153k), so a long joint
  // solve drifted off; without it the energy falls through all 60 iterations and the identity
  // comes out closer (seed 202: surface max 12.2 -> 6.1 mm, origin 4.1 -> 2.4 mm). Tracking
  // keeps it (same errors with or without). 60 GN x 4 PCG: shorter inner solves damp the steps
  // along the weakly determined identity/distance valley (x 16 and x 64 ended at higher
  // energies), and without the drift more iterations keep helping: 40 -> 60 lowered rotation
  // and translation on three 640x480 recordings (docs/tracking-pipeline.md, "Calibration
  // without the point-to-point term").
  // The dense terms on every other pixel, as in the per-frame solves (below): on the five
  // synthetic seeds every error within 0.15 mm (surface max) / 0.06 mm / 0.01 deg / 0.001 of every
  // pixel's, at 0.45-0.6 of the calibration's time, which a reenactment or a live session waits
  // for before its first output frame (docs/real-time.md, "Every other pixel").
  SolverOptions calibration_solver = [] {
    SolverOptions s;
    s.schedule = {{2, 60, 4}};
    s.energy.w_reg = 0.005;
    s.energy.use_point = false;
    s.energy.pixel_sampling = 2;
    return s;
  }();
  // The per-frame solve (paper: 7 GN x 4 PCG on the coarsest level, 1 x 4 on the next), with
  // the sparsity prior on the blendshape weights (EnergyOptions::w_expression_sparsity 0.1):
  // measured on synthetic recordings it halves the expression error and lowers the rotation
  // error (docs/tracking-pipeline.md, "Expression prior"). Calibration keeps the quadratic prior
  // only: with L1 there the identity absorbed more of the expression (translation error x2).
  // A level ends early once an accepted step lowers the energy by less than 3 % (the paper's
  // 7 iterations are the most a frame gets): a face that moved little since the last frame is
  // converged after 2-3 steps, and the rest cost time without moving the fit. Measured on the five
  // synthetic seeds of docs/tracking-pipeline.md (stored landmarks) every error within 0.04 deg /
  // 0.02 mm / 0.003 of the full schedule, and on the webcam clip the solve's synthesis + analysis
  // 47.6 -> 28.0 ms per frame (docs/tracking-pipeline.md, "Early termination").
  // The dense terms on every other pixel (EnergyOptions::pixel_sampling 2), in this solve and the
  // recovery's: the five synthetic seeds' errors within 0.002 mm / 0.01 deg / 0.001 of every
  // pixel's and the real clips' agreement with their landmarks unchanged, at 0.6-0.75 of the
  // analysis time (docs/real-time.md, "Every other pixel").
  SolverOptions tracking_solver = [] {
    SolverOptions s;
    s.energy.w_expression_sparsity = 0.1;
    s.energy.pixel_sampling = 2;
    s.function_tolerance = 0.03;
    return s;
  }();
  // The solve right after a landmark re-initialisation (recovery, and the first frame of a
  // track): more iterations, since it starts farther from the optimum.
  SolverOptions recovery_solver = [] {
    SolverOptions s;
    s.schedule = {{2, 10, 6}, {1, 2, 6}};
    s.energy.w_expression_sparsity = 0.1;
    s.energy.pixel_sampling = 2;
    return s;
  }();
  // The paper's schedule (levels 2 and 1 of the pyramid) assumes a face close to a 640x480
  // camera (~160 px wide). When the face (the extent of its landmarks) is smaller, every
  // schedule is moved to finer levels until the face is at least this many pixels wide on the
  // coarsest solved level (level 0 at most); 0 keeps the schedules as given.
  // Tracking takes 20, the calibration 40 (below): the fitted identity sets the accuracy, the
  // per-frame level the cost. On three 640x480 recordings (landmark extent ~100 px) tracking on
  // the paper's levels after a calibration on levels 1-0 matched tracking on levels 1-0 in every
  // error (surface, rotation, translation, expression, 2D within 0.02 mm / 0.05 deg / 0.05 mm)
  // at a third of the time per frame (26-33 against 82-97 ms); calibrating on the paper's levels
  // too was as fast but fitted worse (seed 202: surface 1.22 against 0.53 mm).
  // docs/tracking-pipeline.md, "Accuracy and speed".
  int min_face_width_px = 20;
  // The other way for a large face (the per-frame solves only): when the face is wider than
  // this on the finest solved level, the schedule moves to coarser levels (the pyramid grows to
  // match) until it is not; it moves back once the face is under 0.8 times this one level finer,
  // so a face near the bound does not switch levels frame by frame. The synthetic actors of the
  // tracker's targets are about 50 px wide on the paper's finest level; a face filling a 720p
  // webcam's frame or a 512x512 portrait clip was solved on 4-9 times their pixels, for the same
  // accuracy (docs/tracking-pipeline.md, "Large faces"). 0 keeps the schedule for any face.
  int max_face_width_px = 96;
  // The same rule for the calibration solve; -1 takes min_face_width_px.
  int calibration_min_face_width_px = 40;
  // Where the calibration's finest level holds the face wider than this, its dense terms take
  // every fourth pixel instead of every other one (EnergyOptions::pixel_sampling 4 for 2), so a
  // large face costs about what one 40-56 px wide does. Level k holds a face at 1/2^k of its
  // width, so the calibration level holds any face at 40-80 px (calibration_min_face_width_px,
  // calibration_max_face_width_px): a 512x512 portrait's at 56-64, twice and a half the pixels
  // of a 640x480 webcam's at 40, and its calibration took 2.5-3.2 times as long (0.8-1.0 against
  // 0.3 s), the wait before a reenactment's first frame; on every fourth pixel 0.67-0.72 of that,
  // every tracker target still met. 0 keeps every other pixel for any face (docs/real-time.md,
  // "The calibration of a large face").
  int calibration_sparse_face_width_px = 56;
  // And a face wider than this on the calibration's level (a HD camera's, close: over 320 px
  // at level 0) is calibrated on coarser levels, as max_face_width_px does for the per-frame
  // solves (the pyramid built deeper to match), never so coarse that it is under
  // calibration_min_face_width_px there: the calibration's level holds any face at 40-80 px, and
  // with the rule above the joint solve's pixels stay within twice a 640x480 webcam face's,
  // whatever the camera. 0 keeps the schedule's level 2 for any large face (docs/real-time.md,
  // "The calibration of a large face").
  int calibration_max_face_width_px = 80;
  LossDetectionOptions loss;
  // Gaze (gaze.h): after each per-frame solve that passed its checks, the eyeLook weights are
  // read from the full-resolution colour around the eyes, which the solve cannot do. On
  // synthetic actors looking aside by 0.2-0.5 it lowered the expression error
  // (docs/tracker.md, "Gaze"). enabled = false leaves the eyeLook weights to the solve.
  GazeOptions gaze;
  // The lids on frames without depth (eye_openness.h): the eyeBlink weights from the detector's
  // eye points, where the colour reader (gaze.read_lids, RGB-D only) cannot read them. Off with
  // gaze.enabled or gaze.read_lids off too.
  EyeOpennessOptions eye_openness;
  // The brows (brow_reader.h): after each fit that passed its checks, the brow blendshapes are
  // read from the detector's brow points against the fit's own brows, on every frame with the
  // points (the solve does not see them: no brows in the paper's 38 landmarks, and a brow barely
  // changes the colour). The calibrated neutral's brow weights are then 0, the rest the reader
  // reads against. enabled = false leaves the brows to the solve.
  BrowReaderOptions brows;
  // Depth against colour (depth_alignment.h), measured on the first calibration frame with depth:
  // a depth map that is not registered to the colour adds its own calibration warning.
  DepthAlignmentOptions depth_alignment;
  // Landmark source the frame adapters should use (rgbd_input.h / the CLI read it; Track()
  // itself takes whatever landmarks the InputFrame carries).
  LandmarkSourceChoice landmark_source = LandmarkSourceChoice::kDetector;
  // Frames before calibration are tracked with the mean identity (so a caller always gets a
  // fit); false skips that per-frame solve (the calibration starts from each frame's landmark
  // pose) and returns kCalibrating without parameters until the calibration is done.
  bool track_while_calibrating = true;
  // Distance (metres) assumed for the pose initialisation when the frame has no depth at the
  // landmarks; refined by the perspective-n-point fit (only its ratio to the face size matters
  // as a start).
  float default_face_distance_m = 0.6f;
  // The owner's stop (e.g. a live session shutting down): when it can be requested it is given to
  // every solve (calibration, tracking, recovery), so a Track() call in progress returns within
  // one Gauss-Newton iteration of the request. A stopped calibration is not applied; its frames
  // are kept for the next Track() call.
  std::stop_token stop;
  // Run the joint calibration solve (and the neutral's re-reads) on a thread of its own
  // ("fr-calibrate"), so that Track() keeps returning at the frame rate while it runs: the frames
  // meanwhile are kCalibrating without a new fit (the last fit held, message "calibrating:
  // fitting the identity ..."), and the first Track() after the solve has finished applies the
  // identity and tracks that frame with it (kCalibrated). The identity is the one the same frames
  // give in the foreground. For live use (the OBS source, the virtual webcam, `send`), where a
  // picture frozen for the seconds of a calibration is worse than a few frames more of
  // calibrating; off for files, where which frame is the first calibrated one must not depend on
  // the machine's speed.
  bool background_calibration = false;
  // The focal length of a camera that does not say (a video file, a webcam; focal_length.h):
  // with `estimate` on, the first calibration over frames without depth searches the field of
  // view that explains the calibration frames' landmarks best, and every later frame without
  // depth is fitted through that camera (its principal point kept): TrackedFrame::camera says
  // which camera each fit is in. Frames with depth keep their own intrinsics. Off by default;
  // the front-ends turn it on for videos and webcams when no --fov / --intrinsics is given.
  FocalLengthOptions focal_length;

  bool IsValid(std::string* why) const;
  // calibration_min_face_width_px with -1 resolved.
  int ResolvedCalibrationMinFaceWidth() const {
    return calibration_min_face_width_px < 0 ? min_face_width_px : calibration_min_face_width_px;
  }
};

// While calibration frames are being collected every frame with a fit is kCalibrating (even when
// its pose was re-initialised); the message says how it was fitted.
enum class TrackingStatus {
  kCalibrating,  // collecting calibration frames; the fit uses the mean (or previous) identity
  kCalibrated,   // this frame completed the calibration; identity/albedo/neutral are now set
  kTracking,     // tracked frame to frame
  kRecovered,    // the pose was re-initialised from the landmarks (after a loss, a jump, or the
                 // first face seen) and the fit is good again
  kLost,         // there is a face (landmarks) but the fit failed the loss checks; parameters
                 // are the best attempt and must not be trusted
  kNoFace,       // too few landmarks: no face in the frame (parameters: the last good ones)
  kBadInput,     // the frame itself is invalid (sizes, non-finite colour...); nothing was done
};
const char* tracking_status_name(TrackingStatus status);
// True for statuses whose `params` are a trustworthy fit of this frame.
bool tracking_status_has_fit(TrackingStatus status);

// Wall-clock milliseconds per stage of one Track() call.
struct StageTimes {
  double landmarks_ms = 0;    // as passed to Track (the adapter's landmark detection)
  double pose_init_ms = 0;    // landmark pose re-initialisation, when it ran
  double pyramid_ms = 0;
  double synthesis_ms = 0;    // rendering inside the solver(s)
  double analysis_ms = 0;     // linearisation, J, PCG inside the solver(s)
  double calibration_ms = 0;  // the joint calibration solve, on the frame that ran it
  double gaze_ms = 0;         // reading the gaze (TrackerOptions::gaze)
  double total_ms = 0;        // everything, including landmarks_ms
};

struct TrackedFrame {
  int64_t frame_index = 0;  // counts Track() calls from 0 (since construction or Reset())
  TrackingStatus status = TrackingStatus::kBadInput;
  std::string message;      // human-readable: why this status ("no face: 3 of 8 landmarks"...)
  // False when there are no parameters at all (kBadInput or kNoFace before any face was
  // fitted); otherwise `params` holds this frame's fit (kLost: the failed attempt) or, for
  // kNoFace and kBadInput, the last good fit held.
  bool has_parameters = false;
  gpu::FaceParameters params;
  TermEnergies energy;      // final energy per term of this frame's solve (finest solved level)
  int64_t residuals = 0;    // residual count of the last Gauss-Newton iteration
  int landmarks_used = 0;   // usable input landmarks (see LossDetectionOptions)
  // Mean distance (px of a 640-wide image) of the input landmarks from the projected fit; -1
  // when there were none.
  double landmark_error_px = -1;
  bool pose_reinitialized = false;  // the pose came from the landmark fit this frame
  // This frame's landmarks were another face's (InputFrame::new_face): the track, the lighting
  // and the calibration started again for it.
  bool new_face = false;
  Termination solver_termination = Termination::kScheduleDone;
  // Gauss-Newton iterations run for this frame, a re-solve's included (the cost of the fit).
  int gauss_newton_iterations = 0;
  // The gaze reading of this frame's fit (ok false: none, and why; the eyeLook weights are then
  // the solve's).
  GazeReading gaze;
  // The brow reading of this frame's fit (ok false: none, and why; the brow weights are then the
  // solve's).
  BrowReading brows;
  // The fit against the frame's landmarks (measured on every frame with parameters of its own;
  // a disagreement made the frame kLost or, re-initialised, kRecovered).
  FitAgreement agreement;
  // Non-empty when this frame's first fit disagreed with the landmarks (the reason): it was then
  // solved again from the landmarks' pose (pose_reinitialized, kRecovered), or kept because that
  // solve left the landmarks' pose too (the message says so, "kept (the landmarks do not fix the
  // pose)"), or the frame was lost.
  std::string disagreement;
  // Whether this frame's fitted light was one no room gives and was moved to the nearest one that
  // is (plausible_light.h), and how far: a fit that keeps needing it has a light the frame does
  // not explain.
  LightProjection light;
  StageTimes times;
  // The camera this frame was fitted through (render `params` with it): the frame's own, or,
  // once the focal length was estimated (TrackerOptions::focal_length), the frame's with the
  // estimated fx, fy.
  gpu::PinholeCamera camera;

  // This frame's first fit disagreed with the landmarks and was not kept: the solve from the
  // landmarks' pose replaced it, or the frame was lost.
  bool fit_refused() const {
    return !disagreement.empty() && (pose_reinitialized || status == TrackingStatus::kLost);
  }
};

// Solve function with CpuSolver::Solve's frame signature; lets a caller put another solver (the
// Vulkan one, which makes the frame's pyramid on the device) behind the tracking loop. The
// solver builds the pyramid (SolverSummary::pyramid_ms).
using FrameSolveFunction = std::function<SolverSummary(const InputFrame& frame, const ParameterLayout& layout,
                                                       const SolverOptions& options, gpu::FaceParameters* params)>;
// Solve function with CpuSolver::SolveFrames' signature (the joint calibration over frames); lets
// a caller put the Vulkan solver behind the calibration.
using FramesSolveFunction =
    std::function<SolverSummary(const std::vector<InputFrame>& frames, const ParameterLayout& layout,
                                const SolverOptions& options, std::vector<gpu::FaceParameters>* params)>;

class FaceTracker {
 public:
  // Throws face_reenact::Error on an invalid model or options.
  FaceTracker(TrackerModel model, const TrackerOptions& options);
  FaceTracker(const FaceModel& model, const TrackerOptions& options);
  ~FaceTracker();
  FaceTracker(const FaceTracker&) = delete;
  FaceTracker& operator=(const FaceTracker&) = delete;

  // One frame, in order. Never throws for frame content: an invalid frame is kBadInput, a
  // frame without a face kNoFace (both hold the last good parameters when there are any). `landmarks_ms` is the time the caller spent producing the
  // frame's landmarks (reported in times.landmarks_ms and counted in times.total_ms).
  TrackedFrame Track(const InputFrame& frame, double landmarks_ms = 0.0);

  // Recalibrate from the next usable frames (the OBS "Calibrate" button). Thread-safe; takes
  // effect at the start of the next Track() call. Tracking goes on meanwhile with the old
  // identity (statuses kCalibrating until the new calibration completes).
  void RequestCalibration();
  // Forgets everything (calibration, previous fit, loss state) as if newly constructed.
  void Reset();

  bool calibrated() const { return calibrated_; }
  // The actor's calibrated identity alpha and albedo beta with the neutral expression delta
  // (the mean over the calibration frames) and the pose/lighting of the first calibration
  // frame. Before calibration: the mean face (alpha = beta = delta = 0) at a frontal pose.
  const gpu::FaceParameters& neutral() const { return neutral_; }
  // Summary of the last joint calibration solve (empty before one ran); with kLowerEnergy, the
  // solve that was kept.
  const SolverSummary& calibration_summary() const { return calibration_summary_; }
  // Which start the last completed calibration kept, and the final energy from each start tried.
  struct CalibrationStartReport {
    CalibrationStart kept = CalibrationStart::kNeutral;  // kNeutral or kPerFrameFits
    double neutral_energy = std::numeric_limits<double>::quiet_NaN();  // NaN: not solved
    double per_frame_fits_energy = std::numeric_limits<double>::quiet_NaN();
    int pixel_sampling = 0;  // the dense terms' EnergyOptions::pixel_sampling in its solve (0: none ran)
    int level = -1;          // the pyramid level it solved on (the finest of its schedule; -1: none ran)
  };
  const CalibrationStartReport& calibration_start_report() const { return calibration_start_report_; }
  // Non-empty when the last calibration's neutral expression says the actor was not at rest
  // (TrackerOptions::rest_warning_weight): names the strongest weights and what to do; or when
  // its first frame with depth has a depth map not registered to its colour (depth_alignment()).
  const std::string& calibration_warning() const { return calibration_warning_; }
  // The search for more relaxed frames after a calibration not at rest
  // (TrackerOptions::relaxed_recalibration_frames).
  struct RelaxedRecalibration {
    bool searched = false;       // a calibration raised the warning and the frames after it were watched
    bool recalibrated = false;   // a calibration on the most relaxed of them was kept
    float first_weight = 0.f;    // the strongest neutral weight the warning counts, before
    float relaxed_weight = 0.f;  // and after that calibration (tried, kept or not; 0: none ran)
    std::vector<int64_t> frame_indices;  // the frames it ran on
    std::string message;         // what happened, in words ("" while watching)
  };
  const RelaxedRecalibration& relaxed_recalibration() const { return relaxed_report_; }
  // True while the frames after a calibration not at rest are watched for a relaxed face: a
  // front-end can ask the actor to relax for a moment.
  bool watching_for_relaxed_face() const { return relaxed_watching_; }
  // The depth/colour alignment of the last calibration's first frame with depth (measured false:
  // none had depth, or why nothing could be measured).
  const DepthAlignment& depth_alignment() const { return depth_alignment_; }
  // The focal length search of the first calibration over frames without depth
  // (TrackerOptions::focal_length); searched false before one ran (or when it is off).
  struct FocalLengthReport {
    bool searched = false;
    FocalLengthEstimate estimate;  // estimated false: the fallback field of view is applied
  };
  const FocalLengthReport& focal_length_report() const { return focal_length_; }
  // The fit of the last frame with a trustworthy fit (has_parameters false before any).
  const TrackedFrame& last_good() const { return last_good_; }
  int calibration_frames_collected() const { return static_cast<int>(calibration_inputs_.size()); }
  // Where a calibration stands, for status lines ("Calibrating: hold still (3 of 5 frames)").
  struct CalibrationProgress {
    bool collecting = false;  // gathering calibration frames (the first calibration, or one requested)
    int frames_collected = 0;
    int frames_needed = 0;
    bool solving = false;     // the joint solve is running in the background (background_calibration)
    double solving_s = 0;     // for this many seconds
    // "3 of 5 frames", "fitting the identity over 5 frames, 1.2 s", or "" when not calibrating.
    std::string Brief() const;
  };
  CalibrationProgress calibration_progress() const;
  // Frame indices (TrackedFrame::frame_index) of the frames collected so far.
  const std::vector<int64_t>& calibration_frame_indices() const { return calibration_frame_indices_; }

  const TrackerOptions& options() const { return options_; }
  const TrackerModel& model() const { return solver_.model(); }
  const CpuSolver& cpu_solver() const { return solver_; }

  // The solver TrackerOptions::solver chose at construction, in words ("cpu (forced)", "vulkan on
  // NVIDIA H200 (discrete, auto)", "cpu (auto: ... a CPU implementation ...)").
  const std::string& solver_description() const { return solver_description_; }
  // Whether that choice was the Vulkan solver (false for the CPU and for a solver set by the
  // program): the live session overlaps frames on two threads when the tracker solves on a GPU.
  bool solves_on_gpu() const { return solves_on_gpu_; }

  // Replace the per-frame (tracking and recovery) solver, e.g. by the Vulkan solver; an empty
  // function restores the CPU solver.
  void SetTrackingSolver(FrameSolveFunction solve);
  // Replace the calibration's joint solver likewise (VulkanSolver::SolveFrames); empty = the CPU's.
  void SetCalibrationSolver(FramesSolveFunction solve);

 private:
  // One solve of one frame (warm-started or from a landmark re-initialisation).
  struct Attempt {
    gpu::FaceParameters params;
    SolverSummary summary;
    double landmark_error_px = -1;
    bool reinit = false;
    std::string pose_message;
    std::string failure;  // empty: passed the loss checks
    bool disagrees = false;  // `failure` is the fit-agreement check's (pose or rotation speed)
    GazeReading gaze;
    BrowReading brows;
    FitAgreement agreement;
    LightProjection light;
  };
  TrackedFrame TrackImpl(const InputFrame& frame, double landmarks_ms);
  // `lids`: the frame's eye-point reading (eye_openness.h), written into the fit's eyeBlink
  // weights before the gaze is read in the opening they leave.
  // `large_face_levels` (optional): the LargeFaceCoarsening carried from frame to frame (the
  // tracking thread's large_face_levels_), read and updated; without it the face's size alone
  // decides (the calibration's re-reads, which may run on another thread).
  Attempt Solve(const InputFrame& input, gpu::FaceParameters start, bool reinit, StageTimes* times,
                const std::stop_token& stop, const EyeOpennessReading* lids = nullptr,
                int* large_face_levels = nullptr) const;
  // The eyes of a fit `*params` of `input`: the lids from the eye points (`lids`, when read) and
  // the gaze, written into its eye weights (after every solve that passed its checks). `use_depth`:
  // the fit had depth terms (the gaze then reads the lids' opening from the colour too).
  GazeReading ReadEyes(const InputFrame& input, const EyeOpennessReading* lids, bool use_depth,
                       gpu::FaceParameters* params, StageTimes* times) const;
  // A joint calibration over a set of frames: its inputs and what it found (face_tracker.cc).
  struct CalibrationOutcome;
  // The thread running one calibration in the background (TrackerOptions::background_calibration).
  class BackgroundCalibration;
  // Calibrates on the collected frames; `current` (frame out->frame_index, fitted from
  // `current_start` when the set does not hold it) gets the new identity's fit, with its eyes read
  // from `lids` and the gaze and its brows (out->brows, read by TrackImpl) as on any tracked frame.
  // `relaxed_of`: see TakeCalibrationFrames.
  void Calibrate(const InputFrame& current, const gpu::FaceParameters& current_start, const EyeOpennessReading* lids,
                 TrackedFrame* out, float relaxed_of = std::numeric_limits<float>::quiet_NaN());
  // The collected frames, taken out of the set (which starts afresh), ready for SolveCalibration.
  // `relaxed_of`: the strongest weight of a calibration not at rest, when these are the most
  // relaxed frames after it (its neutral must beat it to be kept); NaN for an ordinary calibration.
  CalibrationOutcome TakeCalibrationFrames(float relaxed_of);
  // The joint solve(s) and the neutral's re-reads over `o`'s frames; changes no member, so it can
  // run on the background thread while the tracking thread only holds frames. `stop` ends it.
  void SolveCalibration(CalibrationOutcome* o, const std::stop_token& stop) const;
  // Takes a finished calibration's identity and neutral (true), or keeps the old ones: a stopped
  // solve puts its frames back, a failed one leaves a fresh collection (false). *message says which.
  bool ApplyCalibration(CalibrationOutcome* o, std::string* message);
  void StartBackgroundCalibration(float relaxed_of = std::numeric_limits<float>::quiet_NaN());
  // Ends a background calibration under way (a request, a reset, a new solver) without applying it.
  void CancelBackgroundCalibration();
  // Offers a usable frame (with its fit or landmark pose as the joint solve's start) to the
  // calibration set; CalibrationReady says when the set is complete.
  void OfferCalibrationFrame(const InputFrame& input, const gpu::FaceParameters& start, int64_t frame_index);
  bool CalibrationReady() const;
  void ClearCalibrationFrames();
  // Forgets the current track (its fits, energies, unresolved disagreements and the open eyes
  // learned): Reset() and a new face (InputFrame::new_face) start from the landmarks again.
  void ForgetTrack();
  // The camera a frame with `camera` (and depth or not) is fitted through: the estimated focal
  // length once searched, for frames without depth.
  gpu::PinholeCamera FittingCamera(const gpu::PinholeCamera& camera, bool has_depth) const;
  std::string CalibrationProgressMessage() const;  // "calibrating: 3 of 5 frames ..."
  // `stop` (options_.stop, or a background calibration's own) given to a solve.
  SolverOptions WithStop(SolverOptions options, const std::stop_token& stop) const;

  TrackerOptions options_;
  CpuSolver solver_;
  GazeEstimator gaze_;  // reads solver_'s model
  EyeOpennessReader eye_openness_;  // learns the actor's open eyes from the frames seen
  BrowReader brows_;                // learns where the detector puts the actor's brows at rest
  FrameSolveFunction tracking_solve_;
  FramesSolveFunction calibration_solve_;
  std::string solver_description_ = "cpu";
  bool solves_on_gpu_ = false;
  std::atomic<bool> calibration_requested_{false};
  bool calibrated_ = false;
  int large_face_levels_ = 0;  // LargeFaceCoarsening of the last per-frame solve
  bool collecting_ = true;  // gathering calibration frames (first calibration or requested)
  gpu::FaceParameters neutral_;
  gpu::FaceParameters identity_;  // alpha/beta used while tracking (mean face before calibration)
  SolverSummary calibration_summary_;
  CalibrationStartReport calibration_start_report_;
  std::string calibration_warning_;
  DepthAlignment depth_alignment_;
  FocalLengthReport focal_length_;  // applied to frames without depth once searched
  std::vector<InputFrame> calibration_inputs_;
  std::vector<gpu::FaceParameters> calibration_starts_;
  std::vector<int64_t> calibration_frame_indices_;
  int64_t last_calibration_pick_ = -1;
  int calibration_frames_seen_ = 0;  // usable frames offered since the collection started
  // The watch for more relaxed frames (TrackerOptions::relaxed_recalibration_frames).
  struct RelaxedCandidate {
    InputFrame input;
    gpu::FaceParameters params;
    int64_t frame_index = 0;
    float weight = 0.f;  // its strongest weight that the rest warning counts
  };
  bool relaxed_watching_ = false;
  int relaxed_frames_seen_ = 0;
  std::vector<RelaxedCandidate> relaxed_kept_;  // the most relaxed so far, at most calibration_frames
  RelaxedRecalibration relaxed_report_;
  // The strongest weight of `delta` that the rest warning counts (not the gaze, which is
  // absolute, nor the brows the brow reader reads against the rest it learns); *index its blendshape.
  float RestWeight(Eigen::VectorXf delta, int* index = nullptr) const;
  // Offers a tracked frame to the watch; at its end starts the calibration on the kept frames
  // (in the background, or at once into *out).
  void WatchForRelaxedFrame(const InputFrame& input, const EyeOpennessReading* lids, TrackedFrame* out);
  void StopWatchingForRelaxedFrames();
  TrackedFrame previous_;  // last frame's result
  TrackedFrame last_good_;
  bool have_fit_ = false;  // previous_ holds a usable warm start
  std::vector<double> energy_history_;
  int64_t frames_seen_ = 0;
  double previous_timestamp_s_ = std::numeric_limits<double>::quiet_NaN();  // previous_'s frame
  // The pose disagreement a re-solve from the landmarks' pose could not resolve on the last frame
  // (NaN: none): while it stays within 5 degrees of it, no new re-solve is tried.
  double unresolved_disagreement_deg_ = std::numeric_limits<double>::quiet_NaN();
  // Likewise the inner points' distance (FitAgreement::landmark_nme) a frame was kept with.
  double unresolved_landmark_nme_ = std::numeric_limits<double>::quiet_NaN();
  // Last member: destroyed first, so its thread ends before anything it reads goes away.
  std::unique_ptr<BackgroundCalibration> background_;
};

// Pose from landmarks alone (the recovery initialisation): fits the rotation and translation
// that carry the model's landmark vertices (at `shape`'s identity and expression) onto the
// frame's landmarks. With depth at enough landmarks, a 3D-3D rigid alignment of the
// back-projected landmarks starts a perspective-n-point Gauss-Newton refinement; without,
// the start is a frontal pose at the distance that matches the landmarks' spread. Returns
// false (and says why) when there are too few usable landmarks or the fit does not converge;
// on success *euler and *translation hold the pose.
struct PoseInitOptions {
  int min_landmarks = 6;
  float min_confidence = 0.05f;
  int max_iterations = 30;
  float default_distance_m = 0.6f;
  bool inner_landmarks_only = false;  // jaw-line points help the rigid fit (no expression)
  bool use_depth = true;              // the frame's depth at the landmarks (false: landmarks alone)
  bool IsValid(std::string* why) const;
};
struct PoseInitResult {
  bool ok = false;
  std::string message;
  Eigen::Vector3f euler = Eigen::Vector3f::Zero();
  Eigen::Vector3f translation = Eigen::Vector3f::Zero();
  int landmarks_used = 0;
  bool used_depth = false;
  double mean_error_px = 0;  // reprojection error of the used landmarks, pixels of the frame
};
PoseInitResult InitializePoseFromLandmarks(const TrackerModel& model, const InputFrame& frame,
                                           const gpu::FaceParameters& shape, const PoseInitOptions& options);

// `options` with its schedule moved to finer pyramid levels so that a face `face_width_px`
// wide (level-0 pixels) is at least `min_face_width_px` wide on the coarsest solved level.
SolverOptions AdaptScheduleToFaceSize(const SolverOptions& options, double face_width_px, int min_face_width_px);
// How many levels coarser than `options`' schedule a face `face_width_px` wide is solved so that
// it is at most `max_face_width_px` wide on the finest solved level (TrackerOptions::
// max_face_width_px), starting from `current` (the last frame's): up while it is wider, down
// while one level finer would hold it under 0.8 times the bound; never so coarse that the
// coarsest solved level holds it under `min_face_width_px`. 0 when the bound is 0.
int LargeFaceCoarsening(const SolverOptions& options, double face_width_px, int max_face_width_px,
                        int min_face_width_px, int current);
// `options` with its dense terms on every fourth pixel instead of every other one when a face
// `face_width_px` wide (level-0 pixels) is wider than `sparse_face_width_px` on its schedule's
// finest level (TrackerOptions::calibration_sparse_face_width_px; 0: never); any other sampling
// stays.
SolverOptions SparserSamplingForLargeFace(const SolverOptions& options, double face_width_px,
                                          int sparse_face_width_px);
// The calibration's solve for a face `face_width_px` wide (level-0 pixels), as FaceTracker runs
// it: `options.calibration_solver` on the level that holds the face at least
// calibration_min_face_width_px and at most calibration_max_face_width_px wide (AdaptScheduleToFaceSize,
// then LargeFaceCoarsening), on every fourth pixel where it is wider than
// calibration_sparse_face_width_px there (SparserSamplingForLargeFace).
SolverOptions CalibrationSolverForFace(const TrackerOptions& options, double face_width_px);
// The finest pyramid level `options`' schedule solves on (0 for an empty schedule).
int FinestScheduledLevel(const SolverOptions& options);
// `options` solved `levels` pyramid levels coarser (its pyramid deep enough for them).
SolverOptions CoarsenSchedule(const SolverOptions& options, int levels);
// Width (pixels) of the box around the frame's landmarks with confidence > min_confidence; 0
// when there are fewer than two.
double LandmarkExtentPx(const InputFrame& frame, float min_confidence);

// Mean distance, in pixels of a 640-wide image, between the frame's usable landmarks and the
// projections of their model vertices under `params`; -1 when no landmark is usable. `used`
// (optional) receives the number of landmarks counted. Inner landmarks only when
// `inner_only` (the set E_lan uses).
double LandmarkReprojectionError(const TrackerModel& model, const InputFrame& frame, const gpu::FaceParameters& params,
                                 float min_confidence, bool inner_only, int* used = nullptr);

}  // namespace face_reenact::tracker
