// The recording-frame adapter (rgbd_input.h): colour and depth conversion, stored and detected
// landmarks, the head-pose convention fed back to the landmark detector, and bad frames.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/common/srgb.h"
#include "face_reenact/tracker/rgbd_input.h"

namespace face_reenact::tracker {
namespace {

capture::RgbdFrame small_frame(int w = 8, int h = 6) {
  capture::RgbdFrame f;
  f.index = 3;
  f.camera.width = w;
  f.camera.height = h;
  f.camera.fx = f.camera.fy = 10;
  f.camera.cx = (w - 1) * 0.5f;
  f.camera.cy = (h - 1) * 0.5f;
  f.color = cv::Mat(h, w, CV_8UC3, cv::Scalar(10, 128, 250));  // B, G, R
  f.depth = cv::Mat(h, w, CV_32FC1, cv::Scalar(0.8f));
  return f;
}

TEST(RgbdInput, ConvertsColourToLinearRgbAndKeepsDepth) {
  capture::RgbdFrame f = small_frame();
  f.depth.at<float>(1, 2) = std::numeric_limits<float>::quiet_NaN();
  f.depth.at<float>(2, 2) = -1.f;
  f.depth.at<float>(3, 2) = std::numeric_limits<float>::infinity();
  const InputFrame in = MakeInputFrameNoLandmarks(f, /*use_depth=*/true);
  std::string why;
  ASSERT_TRUE(in.IsValid(&why)) << why;
  EXPECT_NEAR(in.color[0], srgb_decode(250 / 255.f), 1e-6);  // R first
  EXPECT_NEAR(in.color[1], srgb_decode(128 / 255.f), 1e-6);
  EXPECT_NEAR(in.color[2], srgb_decode(10 / 255.f), 1e-6);
  ASSERT_TRUE(in.has_depth());
  EXPECT_FLOAT_EQ(in.depth[0], 0.8f);
  EXPECT_EQ(in.depth[1 * 8 + 2], 0.f);  // NaN -> no measurement
  EXPECT_EQ(in.depth[2 * 8 + 2], 0.f);
  EXPECT_EQ(in.depth[3 * 8 + 2], 0.f);
  EXPECT_FALSE(in.depth_valid(2, 1));
  EXPECT_TRUE(in.depth_valid(0, 0));

  const InputFrame rgb_only = MakeInputFrameNoLandmarks(f, /*use_depth=*/false);
  EXPECT_FALSE(rgb_only.has_depth());
}

// A recycled frame's buffers (RgbdInput::Recycle) are written over in full: the next frame converts
// to what a fresh conversion gives, whether the recycled one was of another size, had depth the
// next one lacks, or the other way round; and the recycled buffer is used, not a new one.
TEST(RgbdInput, ARecycledFrameConvertsAsAFreshOne) {
  RgbdInputOptions o;
  o.landmark_source = LandmarkSourceChoice::kRecording;
  o.use_depth = true;
  RgbdInput input(o);
  auto expect_as_fresh = [&](const capture::RgbdFrame& f, const char* what) {
    const InputFrame fresh = MakeInputFrameNoLandmarks(f, true);
    InputFrame got = input.Convert(f);
    EXPECT_EQ(got.color, fresh.color) << what;
    EXPECT_EQ(got.depth, fresh.depth) << what;
    EXPECT_EQ(got.has_depth(), fresh.has_depth()) << what;
    return got;
  };
  capture::RgbdFrame a = small_frame(), b = small_frame(12, 9), no_depth = small_frame();
  b.color.setTo(cv::Scalar(200, 30, 5));
  b.depth.setTo(cv::Scalar(1.5f));
  no_depth.depth = cv::Mat();
  InputFrame first = expect_as_fresh(a, "first");
  const float* buffer = first.color.data();
  input.Recycle(std::move(first));
  InputFrame same = expect_as_fresh(a, "same size, recycled");
  EXPECT_EQ(same.color.data(), buffer) << "the recycled buffer, not a new one";
  input.Recycle(std::move(same));
  input.Recycle(expect_as_fresh(b, "larger"));
  input.Recycle(expect_as_fresh(a, "smaller"));
  input.Recycle(expect_as_fresh(no_depth, "no depth after depth"));
  expect_as_fresh(a, "depth after none");
}

TEST(RgbdInput, RejectsImagesThatDoNotMatchTheCamera) {
  capture::RgbdFrame f = small_frame();
  f.color = cv::Mat(6, 7, CV_8UC3, cv::Scalar(0, 0, 0));
  EXPECT_THROW(MakeInputFrameNoLandmarks(f, true), Error);
  f = small_frame();
  f.color = cv::Mat(6, 8, CV_8UC1, cv::Scalar(0));
  EXPECT_THROW(MakeInputFrameNoLandmarks(f, true), Error);
  f = small_frame();
  f.depth = cv::Mat(6, 8, CV_16UC1, cv::Scalar(0));
  EXPECT_THROW(MakeInputFrameNoLandmarks(f, true), Error);
  EXPECT_NO_THROW(MakeInputFrameNoLandmarks(f, false));  // depth ignored when not used
  f = small_frame();
  f.camera.fx = -1;
  EXPECT_THROW(MakeInputFrameNoLandmarks(f, true), Error);
}

TEST(RgbdInput, StoredLandmarksCarryVisibilityAsConfidence) {
  capture::RgbdFrame f = small_frame();
  EXPECT_TRUE(StoredLandmarks(f, 1.f).empty());
  std::array<capture::LandmarkObservation, capture::kNumLandmarks> lms{};
  for (int k = 0; k < capture::kNumLandmarks; ++k) {
    lms[k].pixel = Eigen::Vector2f(1.f + 0.01f * k, 2.f);
    lms[k].visible = k % 3 != 0;
  }
  lms[5].pixel.x() = std::numeric_limits<float>::quiet_NaN();  // dropped, never passed on
  f.ground_truth.landmarks = lms;
  const auto out = StoredLandmarks(f, 0.7f);
  ASSERT_EQ(out.size(), 67u);
  for (const auto& l : out) {
    EXPECT_NE(l.ibug_index, 5);
    EXPECT_FLOAT_EQ(l.confidence, l.ibug_index % 3 != 0 ? 0.7f : 0.f);
  }

  RgbdInputOptions options;
  options.landmark_source = LandmarkSourceChoice::kRecording;
  RgbdInputInfo info;
  const InputFrame in = MakeInputFrame(f, options, nullptr, &info);
  EXPECT_EQ(in.landmarks.size(), 67u);
  EXPECT_EQ(info.landmarks, 44);  // visible ones (k % 3 != 0), minus none dropped: 45 - 1 (k = 5)
  EXPECT_EQ(info.landmark_status, "ok");
  EXPECT_TRUE(info.depth_used);
  std::string why;
  EXPECT_TRUE(in.IsValid(&why)) << why;
}

TEST(RgbdInput, DetectedLandmarksUseConfidenceAndVisibility) {
  landmarks::LandmarkResult r;
  EXPECT_TRUE(DetectedLandmarks(r, 1.f).empty());
  r.has_landmarks = true;
  for (int k = 0; k < landmarks::kNumLandmarks; ++k) {
    r.points[k] = Eigen::Vector2f(k, k);
    r.confidence[k] = 0.5f;
    r.visible[k] = k != 10;
  }
  const auto out = DetectedLandmarks(r, 0.5f);
  ASSERT_EQ(out.size(), 68u);
  EXPECT_FLOAT_EQ(out[0].confidence, 0.25f);
  EXPECT_FLOAT_EQ(out[10].confidence, 0.f);
}

TEST(RgbdInput, OptionsAndMissingDetector) {
  RgbdInputOptions o;
  o.landmark_source = LandmarkSourceChoice::kRecording;
  std::string why;
  EXPECT_TRUE(o.IsValid(&why)) << why;
  o.stored_landmark_confidence = 0;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("stored_landmark_confidence"), std::string::npos);
  o = RgbdInputOptions();
  o.detector_confidence_scale = 2;
  EXPECT_FALSE(o.IsValid(&why));
  // kDetector without a tracker object is a programming error reported as Error.
  RgbdInputOptions d;
  d.landmark_source = LandmarkSourceChoice::kDetector;
  EXPECT_THROW(MakeInputFrame(small_frame(), d, nullptr), Error);
}

TEST(RgbdInput, HeadPoseConventionMatchesTheLandmarkCode) {
  gpu::FaceParameters p = gpu::frontal_pose(0.6f);
  landmarks::HeadPose pose = HeadPoseFromParameters(p);
  EXPECT_NEAR(pose.yaw_deg, 0, 1e-3);
  EXPECT_NEAR(pose.pitch_deg, 0, 1e-3);
  EXPECT_NEAR(pose.roll_deg, 0, 1e-3);
  // Turning about the model's y axis by +20 degrees moves the nose tip toward +x in the image.
  const Eigen::Vector3f nose_model(0, 0, 0.1f);
  p.euler.y() = static_cast<float>(20 * M_PI / 180);
  const Eigen::Vector3f nose_cam = gpu::rotation_from_euler(p.euler) * nose_model;
  pose = HeadPoseFromParameters(p);
  EXPECT_NEAR(std::abs(pose.yaw_deg), 20, 0.1);
  EXPECT_EQ(pose.yaw_deg > 0, nose_cam.x() > 0);
  // Chin down: the nose points down the image (+y).
  p = gpu::frontal_pose(0.6f);
  p.euler.x() += static_cast<float>(15 * M_PI / 180);
  const Eigen::Vector3f nose2 = gpu::rotation_from_euler(p.euler) * nose_model;
  pose = HeadPoseFromParameters(p);
  EXPECT_NEAR(std::abs(pose.pitch_deg), 15, 0.1);
  EXPECT_EQ(pose.pitch_deg > 0, nose2.y() > 0);
  // Roll: the top of the head moves toward +x for a clockwise (positive) roll.
  p = gpu::frontal_pose(0.6f);
  p.euler.z() = static_cast<float>(10 * M_PI / 180);
  const Eigen::Vector3f top = gpu::rotation_from_euler(p.euler) * Eigen::Vector3f(0, 0.1f, 0);
  pose = HeadPoseFromParameters(p);
  EXPECT_NEAR(std::abs(pose.roll_deg), 10, 0.1);
  EXPECT_EQ(pose.roll_deg > 0, top.x() > 0);
}

}  // namespace
}  // namespace face_reenact::tracker
