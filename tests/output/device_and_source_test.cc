// The writer's errors for things that are not a v4l2loopback output, the command's argument
// errors, and the media sources (a real clip from the shared data when present).
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "face_reenact/capture/media_file.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/subprocess.h"
#include "face_reenact/output/frame_source.h"
#include "face_reenact/output/v4l2_loopback_writer.h"
#include "support/temp_dir.h"

namespace face_reenact::output {
namespace {

namespace fs = std::filesystem;

// One folder per test process, removed when the process exits.
const ::face_reenact::testing::TempDir& temp_dir() {
  static const ::face_reenact::testing::TempDir dir("fr-output-test");
  return dir;
}

std::string open_error(const std::string& device) {
  V4l2LoopbackWriter::Options o;
  o.device = device;
  V4l2LoopbackWriter writer(o);
  try {
    writer.open();
  } catch (const Error& e) {
    EXPECT_FALSE(writer.is_open());
    return e.what();
  }
  return "";
}

TEST(V4l2LoopbackWriter, MissingDeviceSaysHowToCreateOne) {
  std::string e = open_error("/dev/video-does-not-exist-42");
  EXPECT_NE(e.find("does not exist"), std::string::npos) << e;
  // The same options as the package's /etc/modprobe.d/face-reenact.conf and the docs' /dev/video10.
  EXPECT_NE(e.find("modprobe v4l2loopback devices=1 video_nr=10 card_label=\"Face Reenact\" exclusive_caps=1"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("v4l2loopback-dkms"), std::string::npos) << e;
}

TEST(V4l2LoopbackWriter, RegularFileAndDirectoryAreNotVideoDevices) {
  fs::path file = temp_dir() / "not-a-device";
  std::ofstream(file) << "hello";
  std::string e = open_error(file.string());
  EXPECT_NE(e.find("is not a video device"), std::string::npos) << e;
  EXPECT_NE(e.find("regular file"), std::string::npos) << e;
  EXPECT_EQ(fs::file_size(file), 5u);  // never written to
  e = open_error(temp_dir().path());
  EXPECT_NE(e.find("directory"), std::string::npos) << e;
}

TEST(V4l2LoopbackWriter, DevNullIsACharacterDeviceButNotV4l2) {
  std::string e = open_error("/dev/null");
  EXPECT_NE(e.find("not a V4L2 video device"), std::string::npos) << e;
}

TEST(V4l2LoopbackWriter, WritingWhileClosedIsReportedNotCrashed) {
  V4l2LoopbackWriter writer(V4l2LoopbackWriter::Options{});
  std::vector<uint8_t> frame(writer.frame_size());
  std::string why;
  EXPECT_EQ(writer.write_frame(frame, &why), WriteOutcome::kDeviceLost);
  EXPECT_NE(why.find("not open"), std::string::npos);
  EXPECT_FALSE(writer.reopen(&why));
  writer.close();  // idempotent
}

TEST(V4l2LoopbackWriter, OptionsAreValidated) {
  V4l2LoopbackWriter::Options o;
  std::string why;
  EXPECT_TRUE(o.IsValid(&why)) << why;
  EXPECT_EQ(o.width, 1280);
  EXPECT_EQ(o.height, 720);
  EXPECT_EQ(o.format, PixelFormat::kYuyv);
  EXPECT_EQ(o.rate.fps(), 30);
  o.width = 641;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("even"), std::string::npos);
  o.width = 640;
  o.height = 481;
  EXPECT_TRUE(o.IsValid(&why));  // YUYV allows an odd height
  o.format = PixelFormat::kI420;
  EXPECT_FALSE(o.IsValid(&why));
  o.height = 480;
  o.rate = FrameRate{0, 1};
  EXPECT_FALSE(o.IsValid(&why));
  o.rate = FrameRate{30, 1};
  o.device.clear();
  EXPECT_FALSE(o.IsValid(&why));
  o.device = "/dev/video0";
  o.width = 100000;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_THROW(V4l2LoopbackWriter{o}, Error);
}

TEST(V4l2LoopbackWriter, CapsHelpers) {
  EXPECT_TRUE(caps_have_output(0x00000002));   // V4L2_CAP_VIDEO_OUTPUT
  EXPECT_FALSE(caps_have_output(0x00000001));
  EXPECT_TRUE(caps_have_capture(0x00000001));  // V4L2_CAP_VIDEO_CAPTURE
  EXPECT_TRUE(caps_have_capture(0x00001000));  // ..._MPLANE
  EXPECT_FALSE(caps_have_capture(0x05200002));
}

// --- the command -----------------------------------------------------------------------------
SubprocessResult cli(std::vector<std::string> args) {
  const char* exe = std::getenv("FR_CLI");
  args.insert(args.begin(), exe ? exe : "face-reenact");
  return run_subprocess(args);
}

TEST(WebcamCommand, BadDevicesAndArgumentsFailWithAMessage) {
  auto r = cli({"webcam", "--device", "/dev/null", "--seconds", "1"});
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("not a V4L2 video device"), std::string::npos) << r.output;
  r = cli({"webcam", "--device", "/dev/video-missing-7", "--seconds", "1"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("modprobe v4l2loopback"), std::string::npos) << r.output;
  r = cli({"webcam", "--device", "/dev/null", "--format", "rgb24"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("yuyv, i420"), std::string::npos) << r.output;
  r = cli({"webcam", "--device", "/dev/null", "--size", "1280by720"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("WIDTHxHEIGHT"), std::string::npos) << r.output;
  r = cli({"webcam", "--device", "/dev/null", "--fps", "0"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("--fps"), std::string::npos) << r.output;
  r = cli({"webcam", "--device", "/dev/null", "--input", "/nonexistent/clip.mp4"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("does not exist"), std::string::npos) << r.output;
  // The virtual mirror (--mode mirror) with nothing to paint and no light.
  r = cli({"webcam", "--device", "/dev/null", "--target", "/nonexistent/clip.mp4", "--mode", "mirror"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("needs a texture"), std::string::npos) << r.output;
  r = cli({"webcam"});
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--device"), std::string::npos) << r.output;
}

TEST(WebcamCommand, BenchRuns) {
  auto r = cli({"bench", "webcam", "--size", "320x240", "--iterations", "3"});
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("yuyv 320x240"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("i420 320x240"), std::string::npos) << r.output;
}

// --- media sources ---------------------------------------------------------------------------
TEST(MediaSource, StillImageGivesOneFrameThenEnd) {
  fs::path png = temp_dir() / "still.png";
  cv::imwrite(png.string(), cv::Mat(30, 40, CV_8UC3, cv::Scalar(5, 6, 7)));
  EXPECT_TRUE(capture::is_still_image(png.string()));
  auto source = open_media_source({.path = png.string()});
  SourceFrame f;
  std::string err;
  ASSERT_EQ(source->next(&f, &err), SourceStatus::kFrame);
  EXPECT_EQ(f.bgr.size(), cv::Size(40, 30));
  EXPECT_EQ(f.bgr.at<cv::Vec3b>(0, 0), cv::Vec3b(5, 6, 7));
  EXPECT_EQ(source->next(&f, &err), SourceStatus::kEnd);
  EXPECT_NE(source->describe().find("40x30"), std::string::npos);
}

TEST(MediaSource, BadInputsThrowClearErrors) {
  EXPECT_THROW(open_media_source({.path = ""}), Error);
  try {
    open_media_source({.path = "/nonexistent/x.mp4"});
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("does not exist"), std::string::npos);
  }
  EXPECT_THROW(open_media_source({.path = temp_dir().path()}), Error);
  fs::path junk = temp_dir() / "junk.mp4";
  std::ofstream(junk) << "this is not a video at all";
  try {
    open_media_source({.path = junk.string()});
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("junk.mp4"), std::string::npos) << e.what();
  }
  // A damaged PNG (right signature, truncated body).
  fs::path broken = temp_dir() / "broken.png";
  std::vector<uchar> bytes;
  cv::imencode(".png", cv::Mat(64, 64, CV_8UC3, cv::Scalar(1, 2, 3)), bytes);
  std::ofstream(broken, std::ios::binary).write(reinterpret_cast<const char*>(bytes.data()), 40);
  EXPECT_THROW(open_media_source({.path = broken.string()}), Error);
}

TEST(MediaSource, VideoFramesHaveTimestampsAndLoop) {
  fs::path avi = temp_dir() / "clip.avi";
  {
    cv::VideoWriter w(avi.string(), cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 25, cv::Size(64, 48));
    if (!w.isOpened()) GTEST_SKIP() << "OpenCV cannot write MJPG AVI here";
    for (int i = 0; i < 5; ++i) w.write(cv::Mat(48, 64, CV_8UC3, cv::Scalar(40 * i, 0, 0)));
  }
  auto once = open_media_source({.path = avi.string()});
  SourceFrame f;
  std::string err;
  int n = 0;
  while (once->next(&f, &err) == SourceStatus::kFrame) {
    EXPECT_EQ(f.timestamp, std::chrono::milliseconds(40 * n));
    ++n;
  }
  EXPECT_EQ(n, 5);
  auto looping = open_media_source({.path = avi.string(), .loop = true});
  for (int i = 0; i < 12; ++i) {
    ASSERT_EQ(looping->next(&f, &err), SourceStatus::kFrame) << err;
    EXPECT_EQ(f.timestamp, std::chrono::milliseconds(40 * i));  // keeps increasing across loops
    EXPECT_NEAR(f.bgr.at<cv::Vec3b>(24, 32)[0], 40 * (i % 5), 8);
  }
  EXPECT_NE(looping->describe().find("looping"), std::string::npos);
}

TEST(MediaSource, RealWebcamClip) {
  const char* data = std::getenv("FR_SHARED_DATA");
  fs::path clip = fs::path(data ? data : "") / "videos" / "webcam_talking_640x480.wmv";
  if (!data || !fs::exists(clip)) GTEST_SKIP() << "shared data clip not found (set FR_SHARED_DATA): " << clip;
  auto source = open_media_source({.path = clip.string()});
  SourceFrame f;
  std::string err;
  for (int i = 0; i < 10; ++i) {
    ASSERT_EQ(source->next(&f, &err), SourceStatus::kFrame) << err;
    EXPECT_EQ(f.bgr.size(), cv::Size(640, 480));
    EXPECT_EQ(f.bgr.type(), CV_8UC3);
  }
  EXPECT_GT(f.timestamp, std::chrono::nanoseconds(0));
}

TEST(TestPattern, BarsHaveTheirColoursAndTheMarkerMoves) {
  auto source = make_test_pattern_source(640, 480, 30);
  SourceFrame a, b;
  std::string err;
  ASSERT_EQ(source->next(&a, &err), SourceStatus::kFrame);
  ASSERT_EQ(source->next(&b, &err), SourceStatus::kFrame);
  for (int i = 0; i < kTestPatternBars; ++i) {
    cv::Vec3b px = a.bgr.at<cv::Vec3b>(100, i * 80 + 40);
    EXPECT_EQ(px, cv::Vec3b(kTestPatternBarBgr[i][0], kTestPatternBarBgr[i][1], kTestPatternBarBgr[i][2])) << i;
  }
  cv::Mat diff;
  cv::absdiff(a.bgr, b.bgr, diff);
  EXPECT_GT(cv::countNonZero(diff.reshape(1)), 0);
  EXPECT_EQ(cv::countNonZero(diff(cv::Rect(0, 0, 640, 360)).clone().reshape(1)), 0);
  EXPECT_THROW(make_test_pattern_source(0, 480, 30), Error);
}

}  // namespace
}  // namespace face_reenact::output
