// The per-frame pipeline: tracking the target (stored landmarks, CPU renderer frames with
// ground truth), bad input, pass-through of frames without a face, temporal stability.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <future>
#include <limits>
#include <memory>
#include <optional>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/reenact/overlapped_render.h"
#include "face_reenact/reenact/reenactment_pipeline.h"
#include "face_reenact/reenact/transfer.h"
#include "reenact_test_support.h"

namespace face_reenact::reenact {
namespace {

using testing::render_target;
using testing::test_camera;
using testing::test_face;
using testing::test_model;

// A recording-like frame of `params`: colour, depth, ground truth P and landmarks.
capture::RgbdFrame make_frame(const gpu::FaceParameters& params, const gpu::PinholeCamera& cam, int index) {
  const tracker::InputFrame f =
      tracker::RenderSyntheticFrame(testing::test_renderer(), testing::test_tracker_model(), params, cam, {}, 0.25f);
  capture::RgbdFrame out;
  out.index = index;
  out.timestamp_s = index / 30.0;
  out.camera = cam;
  out.color = render_target(params, cam);
  out.depth = cv::Mat(cam.height, cam.width, CV_32FC1);
  for (int j = 0; j < cam.height; ++j)
    for (int i = 0; i < cam.width; ++i) out.depth.at<float>(j, i) = f.depth[static_cast<size_t>(j) * cam.width + i];
  out.ground_truth.params = params;
  std::array<capture::LandmarkObservation, capture::kNumLandmarks> lm{};
  for (const tracker::InputLandmark& l : f.landmarks) {
    lm[static_cast<size_t>(l.ibug_index)].pixel = l.position;
    lm[static_cast<size_t>(l.ibug_index)].visible = l.confidence > 0;
  }
  out.ground_truth.landmarks = lm;
  return out;
}

ReenactmentOptions recording_landmarks() {
  ReenactmentOptions o;
  o.input.landmark_source = tracker::LandmarkSourceChoice::kRecording;
  o.tracker.landmark_source = tracker::LandmarkSourceChoice::kRecording;
  o.tracker.calibration_frames = 2;
  return o;
}

TEST(ReenactPipelineTest, OptionsAreValidated) {
  FR_REQUIRE_MODEL();
  ReenactmentOptions o;
  std::string why;
  EXPECT_TRUE(o.IsValid(&why)) << why;
  o.blend_levels = 11;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_THROW(ReenactmentPipeline(*test_model(), o), Error);
  o = ReenactmentOptions{};
  o.tracker.calibration_frames = 0;
  EXPECT_FALSE(o.IsValid(&why));
  o.use_ground_truth_target = true;  // the tracker's options do not matter then
  EXPECT_TRUE(o.IsValid(&why)) << why;
}

TEST(ReenactPipelineTest, BadFramesPassThroughWithAStatusAndNeverThrow) {
  FR_REQUIRE_MODEL();
  ReenactmentPipeline pipeline(*test_model(), recording_landmarks());
  const gpu::PinholeCamera cam = test_camera(160, 120);
  SourceExpression open;
  open.weights[kJawOpenIndex] = 0.8f;

  capture::RgbdFrame empty;
  empty.camera = cam;
  ReenactedFrame r = pipeline.Process(empty, &open);
  EXPECT_EQ(r.status, TrackingStatus::kLost);
  EXPECT_FALSE(r.reenacted);
  EXPECT_EQ(r.bgr.size(), cv::Size(160, 120));
  EXPECT_NE(r.message.find("no colour"), std::string::npos) << r.message;

  capture::RgbdFrame wrong_type = empty;
  wrong_type.color = cv::Mat::zeros(120, 160, CV_16UC3);
  r = pipeline.Process(wrong_type, &open);
  EXPECT_EQ(r.status, TrackingStatus::kLost);
  EXPECT_EQ(r.bgr.type(), CV_8UC3);

  capture::RgbdFrame wrong_size = empty;
  wrong_size.color = cv::Mat(60, 80, CV_8UC3, cv::Scalar(1, 2, 3));
  r = pipeline.Process(wrong_size, &open);
  EXPECT_EQ(r.status, TrackingStatus::kLost);
  EXPECT_EQ(cv::norm(r.bgr, wrong_size.color, cv::NORM_INF), 0.0);

  // A frame without a face (no landmarks, an empty room, NaN depth): the input, unchanged.
  capture::RgbdFrame no_face = empty;
  no_face.color = cv::Mat(120, 160, CV_8UC3, cv::Scalar(90, 120, 150));
  cv::circle(no_face.color, cv::Point(80, 60), 20, cv::Scalar(10, 200, 30), cv::FILLED);
  no_face.depth = cv::Mat(120, 160, CV_32FC1, cv::Scalar(std::nanf("")));
  r = pipeline.Process(no_face, &open);
  EXPECT_NE(r.status, TrackingStatus::kTracking);
  EXPECT_FALSE(r.reenacted);
  EXPECT_EQ(cv::norm(r.bgr, no_face.color, cv::NORM_INF), 0.0);
  EXPECT_FALSE(r.message.empty());

  // An invalid source expression is a programming error: it throws.
  SourceExpression bad;
  bad.weights[0] = std::nanf("");
  EXPECT_THROW(pipeline.Process(no_face, &bad), Error);
  EXPECT_EQ(pipeline.summary().frames, 4);
}

TEST(ReenactPipelineTest, GroundTruthTargetWithoutGroundTruthIsLost) {
  FR_REQUIRE_MODEL();
  ReenactmentOptions o;
  o.use_ground_truth_target = true;
  ReenactmentPipeline pipeline(*test_model(), o);
  capture::RgbdFrame f;
  f.camera = test_camera(160, 120);
  f.color = cv::Mat(120, 160, CV_8UC3, cv::Scalar(5, 6, 7));
  const ReenactedFrame r = pipeline.Process(f, nullptr);
  EXPECT_EQ(r.status, TrackingStatus::kLost);
  EXPECT_EQ(cv::norm(r.bgr, f.color, cv::NORM_INF), 0.0);
}

TEST(ReenactPipelineTest, GroundTruthTargetTransfersTheSourceMouth) {
  FR_REQUIRE_MODEL();
  ReenactmentOptions o;
  o.use_ground_truth_target = true;
  ReenactmentPipeline pipeline(*test_model(), o);
  const gpu::PinholeCamera cam = test_camera(160, 120);
  const capture::RgbdFrame f = make_frame(test_face(0.4f), cam, 0);
  SourceExpression open;
  open.weights[kJawOpenIndex] = 0.7f;
  const ReenactedFrame r = pipeline.Process(f, &open);
  ASSERT_TRUE(r.reenacted) << r.message;
  EXPECT_TRUE(r.mouth_drawn);
  EXPECT_FLOAT_EQ(r.output_params.delta[kJawOpenIndex], 0.7f);
  EXPECT_GT(cv::norm(r.bgr, f.color, cv::NORM_L1), 0.0);
  ASSERT_FALSE(r.depth.empty());
  // The output depth is the rendered face's where it was drawn, with a hole in the open mouth.
  EXPECT_EQ(r.depth.size(), f.depth.size());
  // Off: the input, exactly.
  o.mode = ReenactMode::kOff;
  pipeline.SetOptions(o);
  const ReenactedFrame off = pipeline.Process(f, &open);
  EXPECT_FALSE(off.reenacted);
  EXPECT_EQ(cv::norm(off.bgr, f.color, cv::NORM_INF), 0.0);
}

// The mirror mode (the OBS source's and the webcam's `mirror`): the target's own expression, its
// face re-lit; the source expression is ignored; a mirror with nothing to do is refused.
TEST(ReenactPipelineTest, MirrorModeReLightsTheTargetsOwnFace) {
  FR_REQUIRE_MODEL();
  ReenactmentOptions o;
  o.use_ground_truth_target = true;
  o.mode = ReenactMode::kMirror;
  std::string why;
  EXPECT_FALSE(o.IsValid(&why)) << "a mirror without a texture or a light";
  EXPECT_THROW(ReenactmentPipeline(*test_model(), o), Error);
  o.mirror.light = ParseLightPreset("left");
  ASSERT_TRUE(o.IsValid(&why)) << why;
  ReenactmentPipeline pipeline(*test_model(), o);
  const gpu::PinholeCamera cam = test_camera(160, 120);
  const capture::RgbdFrame f = make_frame(test_face(0.4f), cam, 0);
  SourceExpression open;
  open.weights[kJawOpenIndex] = 0.7f;
  const ReenactedFrame r = pipeline.Process(f, &open);
  ASSERT_TRUE(r.reenacted) << r.message;
  EXPECT_FALSE(r.mouth_drawn);
  EXPECT_FLOAT_EQ(r.output_params.delta[kJawOpenIndex], f.ground_truth.params->delta[kJawOpenIndex]);
  EXPECT_GT(cv::norm(r.bgr, f.color, cv::NORM_L1), 1000.0);
}

// Tracking a static target: after calibration every frame is reenacted, and the output does not
// flicker: consecutive outputs differ far less than the reenactment changes the frame.
TEST(ReenactPipelineTest, TrackedStaticTargetIsStableFrameToFrame) {
  FR_REQUIRE_MODEL();
  ReenactmentPipeline pipeline(*test_model(), recording_landmarks());
  const gpu::PinholeCamera cam = test_camera(160, 120);
  gpu::FaceParameters p = test_face(0.4f);
  const capture::RgbdFrame f = make_frame(p, cam, 0);
  SourceExpression smile;
  smile.weights[arkit_blendshape_index("mouthSmileLeft")] = 0.8f;
  smile.weights[arkit_blendshape_index("mouthSmileRight")] = 0.8f;
  smile.weights[kJawOpenIndex] = 0.4f;
  std::vector<ReenactedFrame> outs;
  for (int i = 0; i < 6; ++i) {
    capture::RgbdFrame fi = f;
    fi.index = i;
    outs.push_back(pipeline.Process(fi, &smile));
  }
  EXPECT_EQ(outs[0].status, TrackingStatus::kCalibrating);
  int reenacted = 0;
  for (const auto& o : outs) reenacted += o.reenacted;
  ASSERT_GE(reenacted, 3) << outs.back().message;
  const ReenactedFrame& a = outs[outs.size() - 2];
  const ReenactedFrame& b = outs.back();
  ASSERT_TRUE(a.reenacted && b.reenacted);
  cv::Mat d;
  cv::absdiff(a.bgr, b.bgr, d);
  const double flicker = cv::mean(d, a.face_mask)[2];
  cv::absdiff(b.bgr, f.color, d);
  const double change = cv::mean(d, a.face_mask)[2];
  RecordProperty("flicker", std::to_string(flicker));
  RecordProperty("change", std::to_string(change));
  EXPECT_LT(flicker, 1.0);
  EXPECT_GT(change, 2.0);
  EXPECT_GT(pipeline.summary().reenacted_frames, 0);
  // Recalibration on request.
  pipeline.RequestCalibration();
  capture::RgbdFrame again = f;
  again.index = 6;
  const ReenactedFrame c = pipeline.Process(again, &smile);
  EXPECT_EQ(c.tracked.status, tracker::TrackingStatus::kCalibrating);
  EXPECT_EQ(c.status, TrackingStatus::kCalibrating);
}

// The split of the live session and of OverlappedRender (`reenact`): Track(n+1) on one
// thread while Render(n) runs on another gives the same frames, bit for bit, as Process one frame
// after the other (Render keeps the appearance, the neutral of Eq. 15 travels with each frame, so
// the overlap changes nothing), through a calibration, a moving head and a recalibration request
// in the middle.
// Eight frames of a turning head (calibration 0-1, tracking 2-4, recalibration 5-6, tracking 7),
// a smile to transfer, and what Process gives frame by frame: what the split ways must equal.
struct SplitPipelineCase {
  std::vector<capture::RgbdFrame> frames;
  SourceExpression smile;
  std::vector<ReenactedFrame> expected;
  int expected_frames = 0, expected_reenacted = 0;
  static constexpr size_t kRecalibrateAt = 5;

  SplitPipelineCase() {
    const gpu::PinholeCamera cam = test_camera(160, 120);
    for (int i = 0; i < 8; ++i) {
      gpu::FaceParameters p = test_face(0.4f);
      p.euler.y() += 0.02f * static_cast<float>(i);
      frames.push_back(make_frame(p, cam, i));
    }
    smile.weights[arkit_blendshape_index("mouthSmileLeft")] = 0.7f;
    smile.weights[kJawOpenIndex] = 0.3f;
    ReenactmentPipeline sequential(*test_model(), recording_landmarks());
    for (size_t i = 0; i < frames.size(); ++i) {
      if (i == kRecalibrateAt) sequential.RequestCalibration();
      expected.push_back(sequential.Process(frames[i], &smile));
    }
    expected_frames = sequential.summary().frames;
    expected_reenacted = sequential.summary().reenacted_frames;
  }

  void ExpectSame(const std::vector<ReenactedFrame>& got, const ReenactmentPipeline& split) const {
    ASSERT_EQ(got.size(), expected.size());
    int reenacted = 0;
    for (size_t i = 0; i < got.size(); ++i) {
      EXPECT_EQ(got[i].status, expected[i].status) << "frame " << i;
      EXPECT_EQ(got[i].reenacted, expected[i].reenacted) << "frame " << i;
      reenacted += got[i].reenacted;
      ASSERT_EQ(got[i].bgr.size(), expected[i].bgr.size());
      EXPECT_EQ(cv::norm(got[i].bgr, expected[i].bgr, cv::NORM_INF), 0.0) << "frame " << i;
    }
    EXPECT_GE(reenacted, 3);
    EXPECT_EQ(split.summary().frames, expected_frames);
    EXPECT_EQ(split.summary().reenacted_frames, expected_reenacted);
  }
};

TEST(ReenactPipelineTest, TrackAndRenderOverlappedOnTwoThreadsGiveProcessFrames) {
  FR_REQUIRE_MODEL();
  const SplitPipelineCase c;
  const auto& frames = c.frames;
  // The same frames through OverlappedRender (what `reenact` uses): each frame's Track
  // runs while the frame before renders on the helper's thread, and frames finish in order.
  ReenactmentPipeline split(*test_model(), recording_landmarks());
  std::vector<ReenactedFrame> got;
  std::vector<size_t> finished;
  struct Index {
    size_t i;
  };
  {
    OverlappedRender<Index> overlap(split, [&](Index& f, const ReenactedFrame& out) {
      finished.push_back(f.i);
      got.push_back(out);
    });
    for (size_t i = 0; i < frames.size(); ++i) {
      if (i == c.kRecalibrateAt) split.RequestCalibration();
      overlap.Push(std::make_unique<Index>(Index{i}), split.Track(frames[i]), &c.smile);
      EXPECT_EQ(got.size(), i) << "frame " << i << " renders while the next is tracked";
    }
    overlap.Drain();
  }
  ASSERT_EQ(finished.size(), frames.size());
  for (size_t i = 0; i < finished.size(); ++i) EXPECT_EQ(finished[i], i);
  c.ExpectSame(got, split);
}

// The live session's landmark stage (LiveSession::Options::landmarks_ahead): frame n+1 prepared on
// another thread while frame n is tracked, a recalibration requested between. With the recording's
// landmarks (no detector: the pose Track hands back is not read) every output equals Process's;
// the sanitizer build runs both threads on the one pipeline under ASan.
TEST(ReenactPipelineTest, FramesPreparedAheadOnAnotherThreadGiveProcessFrames) {
  FR_REQUIRE_MODEL();
  const SplitPipelineCase c;
  ReenactmentPipeline ahead(*test_model(), recording_landmarks());
  std::vector<ReenactedFrame> got;
  auto prepare = [&](size_t i) {
    return std::async(std::launch::async, [&ahead, &c, i] { return ahead.Prepare(c.frames[i]); });
  };
  std::future<PreparedTarget> next = prepare(0);
  for (size_t i = 0; i < c.frames.size(); ++i) {
    PreparedTarget prepared = next.get();
    EXPECT_EQ(prepared.tracked.frame.frame_index, c.frames[i].index);
    EXPECT_FALSE(prepared.tracked.finished) << "frame " << i;
    if (i + 1 < c.frames.size()) next = prepare(i + 1);
    if (i == c.kRecalibrateAt) ahead.RequestCalibration();
    got.push_back(ahead.Render(ahead.Track(std::move(prepared)), &c.smile));
  }
  c.ExpectSame(got, ahead);
}

// A frame Prepare refuses (no colour) is finished there, and Track passes it on unchanged.
TEST(ReenactPipelineTest, AFramePrepareRefusesPassesThroughTrack) {
  FR_REQUIRE_MODEL();
  ReenactmentPipeline pipeline(*test_model(), recording_landmarks());
  capture::RgbdFrame empty;
  empty.camera = test_camera(160, 120);
  PreparedTarget prepared = pipeline.Prepare(empty);
  EXPECT_TRUE(prepared.tracked.finished);
  const ReenactedFrame out = pipeline.Render(pipeline.Track(std::move(prepared)), nullptr);
  EXPECT_EQ(out.status, TrackingStatus::kLost);
  EXPECT_FALSE(out.reenacted);
  EXPECT_NE(out.message.find("no colour image"), std::string::npos) << out.message;
  EXPECT_EQ(out.bgr.size(), cv::Size(160, 120));
}

// A Render that throws (an invalid source expression: a caller's error) surfaces where its frame
// is finished, at the next Push, with the frames before it finished in order; the frame queued
// behind it still renders before the helper goes (no crash, no hang, nothing read after it is
// freed).
TEST(ReenactPipelineTest, OverlappedRenderRethrowsARenderErrorWhereItsFrameIsFinished) {
  FR_REQUIRE_MODEL();
  SourceExpression good, bad;
  bad.weights[kJawOpenIndex] = std::numeric_limits<float>::quiet_NaN();
  ASSERT_FALSE(bad.IsValid(nullptr));
  ReenactmentPipeline pipeline(*test_model(), recording_landmarks());
  // Frames Track left nothing to render for (as for a frame without a face): Render checks the
  // source expression, then books them. No tracking: the test is about the helper, and stays short
  // under the sanitizers, which check its hand-over and its destruction.
  auto tracked = [](int i) {
    TrackedTarget t;
    t.finished = true;
    t.frame.bgr = cv::Mat(24, 32, CV_8UC3, cv::Scalar(i, i, i));
    t.start = std::chrono::steady_clock::now();
    return t;
  };
  std::vector<int> finished;
  struct Index {
    int i;
  };
  {
    OverlappedRender<Index> overlap(pipeline, [&](Index& f, const ReenactedFrame& out) {
      EXPECT_EQ(out.bgr.at<cv::Vec3b>(0, 0)[0], f.i) << "frame " << f.i << " got another frame's output";
      finished.push_back(f.i);
    });
    overlap.Push(std::make_unique<Index>(Index{0}), tracked(0), &good);
    overlap.Push(std::make_unique<Index>(Index{1}), tracked(1), &bad);
    EXPECT_EQ(finished, std::vector<int>({0}));
    EXPECT_THROW(overlap.Push(std::make_unique<Index>(Index{2}), tracked(2), &good), Error);
    EXPECT_EQ(finished, std::vector<int>({0}));  // frame 1 threw; frame 2 is still rendering
  }  // the helper lets frame 2 finish rendering before the pipeline and the frame go
  EXPECT_EQ(pipeline.summary().frames, 2);  // frames 0 and 2 rendered; frame 1 was refused
}

// The overlay mode (OBS, the webcam, `reenact --mode overlay`): the target is tracked and its
// fit drawn over it instead of re-rendered: the fitted landmarks (red) sit on the frame's own
// (green), the mesh's edges change pixels only around the face, and nothing is reenacted.
TEST(ReenactPipelineTest, OverlayModeDrawsTheFitOverTheTarget) {
  FR_REQUIRE_MODEL();
  ReenactmentOptions o = recording_landmarks();
  o.mode = ReenactMode::kOverlay;
  ReenactmentPipeline pipeline(*test_model(), o);
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const gpu::FaceParameters p = test_face(0.4f);
  const capture::RgbdFrame f = make_frame(p, cam, 0);
  ReenactedFrame out;
  for (int i = 0; i < 4; ++i) {
    capture::RgbdFrame fi = f;
    fi.index = i;
    out = pipeline.Process(fi, nullptr);
  }
  ASSERT_EQ(out.status, TrackingStatus::kTracking) << out.message;
  EXPECT_FALSE(out.reenacted);
  ASSERT_EQ(out.bgr.size(), f.color.size());
  // Where the overlay drew: a box around the face's landmarks (the mesh reaches the scalp and
  // the neck beyond them), nowhere far from it.
  cv::Mat diff, changed;
  cv::absdiff(out.bgr, f.color, diff);
  cv::cvtColor(diff, changed, cv::COLOR_BGR2GRAY);
  cv::Rect face_box;
  {
    std::vector<cv::Point> pts;
    for (const auto& l : *f.ground_truth.landmarks)
      if (l.visible) pts.emplace_back(static_cast<int>(l.pixel.x()), static_cast<int>(l.pixel.y()));
    face_box = cv::boundingRect(pts);
  }
  const int grow = face_box.width;  // the head around the face
  const cv::Rect head(face_box.x - grow, face_box.y - grow, face_box.width + 2 * grow, face_box.height + 2 * grow);
  cv::Mat outside = changed.clone();
  outside(head & cv::Rect(0, 0, cam.width, cam.height)).setTo(0);
  outside(cv::Rect(0, 0, cam.width, 30)).setTo(0);  // the status line
  EXPECT_EQ(cv::countNonZero(outside > 8), 0);
  EXPECT_GT(cv::countNonZero(changed(face_box) > 8), face_box.area() / 10);  // edges and dots on the face
  // A fitted landmark (red ring) around each detected one (green dot): the nose tip's pixel is
  // green, and red is drawn within 3 px of it.
  const Eigen::Vector2f nose = (*f.ground_truth.landmarks)[30].pixel;
  const cv::Vec3b c = out.bgr.at<cv::Vec3b>(static_cast<int>(std::lround(nose.y())), static_cast<int>(std::lround(nose.x())));
  EXPECT_GT(c[1], c[0] + 60) << "not green at the nose tip: " << c;
  int red = 0;
  for (int dj = -3; dj <= 3; ++dj)
    for (int di = -3; di <= 3; ++di) {
      const cv::Vec3b q = out.bgr.at<cv::Vec3b>(static_cast<int>(std::lround(nose.y())) + dj, static_cast<int>(std::lround(nose.x())) + di);
      red += q[2] > q[1] + 60 && q[2] > q[0] + 60;
    }
  EXPECT_GT(red, 0);
}

}  // namespace
}  // namespace face_reenact::reenact
