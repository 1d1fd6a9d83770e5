// Tracking on real videos: the face is found in nearly every frame, tracking is no less
// stable than detecting on every frame, a group shot's person in front is followed (and only
// a much larger face elsewhere takes the track over),
// and smoothing lowers jitter without losing the face.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <filesystem>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/common/subprocess.h"
#include "face_reenact/landmarks/evaluation.h"
#include "face_reenact/landmarks/landmark_tracker.h"
#include "test_data.h"

namespace face_reenact::landmarks {
namespace {

TEST(TrackerVideoTest, TrackingFindsTheFaceAndIsAsStableAsDetection) {
  FR_REQUIRE_MODEL();
  FR_REQUIRE_SHARED(video, "videos/webcam_talking_640x480.wmv");
  const VideoReport report = video_report(video, TrackerOptions{}, 0);
  ASSERT_EQ(report.modes.size(), 3u);
  EXPECT_EQ(report.width, 640);
  EXPECT_EQ(report.height, 480);
  const VideoModeReport& tracking = report.modes[0];
  const VideoModeReport& smoothed = report.modes[1];
  const VideoModeReport& every = report.modes[2];
  EXPECT_EQ(tracking.frames, 288);
  EXPECT_GE(tracking.frames_with_landmarks, int(0.97 * tracking.frames));
  EXPECT_GE(every.frames_with_landmarks, int(0.97 * every.frames));
  // Tracking searches rarely: the first frame and the periodic band checks.
  EXPECT_GE(tracking.summary.tracked_frames, int64_t(0.8 * tracking.frames));
  EXPECT_LE(tracking.summary.full_searches, 5);
  EXPECT_EQ(every.summary.full_searches, every.frames);
  // Jitter (head motion removed) is not worse than per-frame detection.
  EXPECT_LE(tracking.jitter_motion_compensated, every.jitter_motion_compensated * 1.05)
      << tracking.jitter_motion_compensated << " vs " << every.jitter_motion_compensated;
  EXPECT_LT(smoothed.jitter_motion_compensated, tracking.jitter_motion_compensated);
  // Smoothing must follow real motion: raw displacement (which includes the head's motion)
  // stays close to the unsmoothed one rather than collapsing.
  EXPECT_GT(smoothed.jitter_raw, 0.7 * tracking.jitter_raw);
  EXPECT_EQ(smoothed.frames_with_landmarks, tracking.frames_with_landmarks);
}

TEST(TrackerVideoTest, FollowsThePersonInFrontInAGroupShot) {
  FR_REQUIRE_MODEL();
  FR_REQUIRE_SHARED(video, "videos/multi_face.avi");
  TrackerOptions options;
  const VideoModeReport m = run_video_mode(video, options, "tracking", 420);
  EXPECT_EQ(m.frames, 420);
  EXPECT_GE(m.frames_with_landmarks, int(0.9 * m.frames));
  // On frame 0 the man in front has his head turned and the detector finds only the man at the
  // back right (a 73 px face). The tracker must leave him for the face in front (about 146 px)
  // at its first search for a more prominent face, and follow that one from then on.
  EXPECT_EQ(m.summary.face_switches, 1) << m.summary.BriefReport();
  // Between consecutive frames with a face the box jumps to another person only onto a face at
  // least prominent_face_area_ratio times larger, or after the followed face has been missing
  // for reacquire_frames frames.
  int gap = 0;
  const Box* last = nullptr;
  int switches = 0;
  for (size_t i = 0; i < m.boxes.size(); ++i) {
    const Box& b = m.boxes[i];
    if (b.width <= 0) {
      ++gap;
      continue;
    }
    if (last != nullptr) {
      const float jump = (b.center() - last->center()).norm() / std::max(b.width, last->width);
      if (jump > 1.0f) {
        ++switches;
        EXPECT_TRUE(gap >= options.reacquire_frames || b.area() >= options.prominent_face_area_ratio * last->area())
            << "person switched at frame " << i << " after a gap of " << gap << " to a box of " << b.width << " px from "
            << last->width << " px";
      }
    }
    gap = 0;
    last = &b;
  }
  EXPECT_EQ(switches, 1);
  // After the first search (frame 30 and a margin) the followed face is the one in front.
  const size_t after = size_t(options.prominent_face_interval) + 10;
  int in_front = 0;
  for (size_t i = after; i < m.boxes.size(); ++i) in_front += m.boxes[i].width >= 0.15f * 640.f;
  EXPECT_GE(in_front, int(0.9 * double(m.boxes.size() - after)));
}

TEST(TrackerVideoTest, NoSearchForAProminentFaceWhileTheFollowedOneIsLarge) {
  FR_REQUIRE_MODEL();
  FR_REQUIRE_SHARED(video, "videos/webcam_talking_640x480.wmv");
  // The person at the camera fills more than a fifth of the frame width: the tracker never pays
  // a whole-frame search for someone more prominent.
  const VideoModeReport m = run_video_mode(video, TrackerOptions{}, "tracking", 90);
  EXPECT_EQ(m.summary.prominent_searches, 0) << m.summary.BriefReport();
  EXPECT_EQ(m.summary.face_switches, 0);
}

TEST(TrackerVideoTest, TrackingIsAsStableAsDetectionOnATalkingHead) {
  FR_REQUIRE_MODEL();
  FR_REQUIRE_SHARED(video, "videos/liveportrait_d0.mp4");
  TrackerOptions every;
  every.detect_every_frame = true;
  const VideoModeReport t = run_video_mode(video, TrackerOptions{}, "tracking", 0);
  const VideoModeReport e = run_video_mode(video, every, "detect_every_frame", 0);
  EXPECT_EQ(t.frames_with_landmarks, t.frames);
  EXPECT_LE(t.jitter_motion_compensated, e.jitter_motion_compensated * 1.05)
      << t.jitter_motion_compensated << " vs " << e.jitter_motion_compensated;
}

TEST(TrackerVideoTest, OtherVideosAreTracked) {
  FR_REQUIRE_MODEL();
  for (const char* name : {"videos/liveportrait_d0.mp4", "videos/liveportrait_d10.mp4"}) {
    const std::string video = test::shared_path(name);
    if (video.empty()) GTEST_SKIP() << "real test data '" << name << "' not found: set FR_SHARED_DATA";
    const VideoModeReport m = run_video_mode(video, TrackerOptions{}, "tracking", 120);
    EXPECT_GE(m.frames_with_landmarks, int(0.9 * m.frames)) << name << ": " << m.summary.BriefReport();
  }
}

TEST(TrackerTest, SurvivesBadFramesSizeChangesAndReset) {
  FR_REQUIRE_MODEL();
  FR_REQUIRE_SHARED(path, "faces-68/lfpw/image_0001.png");
  const Image face = load_image(path);
  LandmarkTracker tracker;
  EXPECT_TRUE(tracker.Track(face.view(), 0.0).ok());
  EXPECT_TRUE(tracker.tracking());
  EXPECT_EQ(tracker.Track(ImageView{}, 0.033).status, DetectionStatus::kInvalidInput);
  LandmarkResult r = tracker.Track(face.view(), 0.066);
  EXPECT_TRUE(r.ok());
  EXPECT_EQ(r.source, LandmarkSource::kTracked);
  std::vector<uint8_t> black(641 * 479 * 3, 0);
  r = tracker.Track(ImageView{black.data(), 641, 479, 0, PixelFormat::kBGR8}, 0.1);
  EXPECT_FALSE(r.ok());
  std::vector<uint8_t> tiny(40 * 30, 0);
  r = tracker.Track(ImageView{tiny.data(), 40, 30, 0, PixelFormat::kGray8}, 0.13);
  EXPECT_EQ(r.status, DetectionStatus::kFaceTooSmall);
  tracker.Reset();
  EXPECT_FALSE(tracker.tracking());
  r = tracker.Track(face.view(), 0.2);
  EXPECT_TRUE(r.ok()) << r.reason;
  EXPECT_EQ(r.source, LandmarkSource::kDetected);
  EXPECT_GE(tracker.summary().frames, 6);
  EXPECT_FALSE(tracker.summary().BriefReport().empty());
}

TEST(TrackerTest, PoseIsAppliedToTrackedFrames) {
  FR_REQUIRE_MODEL();
  FR_REQUIRE_SHARED(path, "faces-68/lfpw/image_0001.png");
  const Image face = load_image(path);
  LandmarkTracker tracker;
  const HeadPose pose{-45.f, 0, 0};
  tracker.Track(face.view(), 0.0);
  const LandmarkResult r = tracker.Track(face.view(), 0.05, &pose);
  ASSERT_TRUE(r.has_landmarks);
  int hidden = 0;
  for (bool v : r.visible) hidden += !v;
  EXPECT_GT(hidden, 20);
  EXPECT_FALSE(r.visible[36]);  // -yaw: the -x half (subject's right here) turns away
  EXPECT_TRUE(r.visible[45]);
}

TEST(TrackerOptionsTest, RejectsBadOptions) {
  TrackerOptions o;
  std::string error;
  EXPECT_TRUE(o.IsValid(&error)) << error;
  o.redetect_interval = -1;
  EXPECT_FALSE(o.IsValid(&error));
  o = TrackerOptions{};
  o.prominent_face_area_ratio = 0.5f;  // a smaller face is never more prominent
  EXPECT_FALSE(o.IsValid(&error));
  o = TrackerOptions{};
  o.prominent_face_max_width = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(o.IsValid(&error));
  o = TrackerOptions{};
  o.smoothing.min_cutoff_hz = 0;
  EXPECT_FALSE(o.IsValid(&error));
  EXPECT_THROW(LandmarkTracker{o}, Error);
  o = TrackerOptions{};
  o.detector.confidence_samples = 0;
  EXPECT_THROW(LandmarkTracker{o}, Error);
}

TEST(CliVideoTest, InputVideoWritesJsonAndDrawings) {
  FR_REQUIRE_MODEL();
  FR_REQUIRE_SHARED(video, "videos/webcam_talking_640x480.wmv");
  const char* cli = std::getenv("FR_CLI");
  ASSERT_NE(cli, nullptr);
  const auto dir = test::temp_dir("fr_landmarks_cli_video");
  const std::string json = (dir / "out.json").string(), frames = (dir / "frames").string(),
                    sheet = (dir / "sheet.png").string();
  SubprocessResult run = run_subprocess(
      {cli, "landmarks", "--input", video, "--max-frames", "12", "--out", json, "--draw", frames});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const nlohmann::json j = nlohmann::json::parse(test::read_text(json));
  EXPECT_EQ(j["kind"], "video");
  ASSERT_EQ(j["frames"].size(), 12u);
  for (const auto& f : j["frames"]) {
    EXPECT_EQ(f["status"], "ok");
    EXPECT_EQ(f["points"].size(), 68u);
    EXPECT_EQ(f["confidence"].size(), 68u);
  }
  EXPECT_TRUE(std::filesystem::exists(std::filesystem::path(frames) / "frame_000011.png"));
  run = run_subprocess({cli, "landmarks", "--input", video, "--max-frames", "6", "--draw", sheet});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_GT(std::filesystem::file_size(sheet), 1000u);
  run = run_subprocess({cli, "landmarks", "--video-report", video, "--max-frames", "20", "--json"});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const nlohmann::json rep = nlohmann::json::parse(run.output);
  ASSERT_EQ(rep["modes"].size(), 3u);
  EXPECT_EQ(rep["modes"][0]["frames"], 20);
  EXPECT_TRUE(rep["modes"][0].contains("ms_p95"));
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace face_reenact::landmarks
