// The recording format: writer/reader round trip and every validation path of the reader.
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>

#include <opencv2/imgcodecs.hpp>

#include "capture_test_support.h"
#include "face_reenact/capture/recording.h"
#include "face_reenact/common/error.h"

namespace face_reenact::capture {
namespace {
namespace fs = std::filesystem;
using testing::replace_in_file;
using testing::slurp;
using testing::spit;
using testing::TempDir;

constexpr int kW = 32, kH = 24;

RecordingInfo small_info() {
  RecordingInfo info;
  info.camera.width = kW;
  info.camera.height = kH;
  info.camera.fx = 40.5f;
  info.camera.fy = 41.25f;
  info.camera.cx = 15.75f;
  info.camera.cy = 11.5f;
  info.fps = 25;
  info.source = "unit test";
  info.generator = "recording_test";
  return info;
}

RgbdFrame make_frame(int index, bool with_truth) {
  RgbdFrame f;
  f.index = index;
  f.timestamp_s = index / 25.0;
  f.camera = small_info().camera;
  f.color = cv::Mat(kH, kW, CV_8UC3);
  cv::RNG rng(static_cast<uint64_t>(index) + 1);  // the same frame every call
  rng.fill(f.color, cv::RNG::UNIFORM, 0, 256);
  f.depth = cv::Mat(kH, kW, CV_32FC1);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) f.depth.at<float>(y, x) = 0.4f + 0.001f * static_cast<float>((x * 131 + y * 17 + index * 7) % 5000);
  f.depth.at<float>(0, 0) = 0.0f;
  f.depth.at<float>(0, 1) = std::numeric_limits<float>::quiet_NaN();
  f.depth.at<float>(0, 2) = -1.0f;
  f.depth.at<float>(0, 3) = 70.0f;  // beyond 65.535 m: not representable, written as no data
  f.depth.at<float>(0, 4) = 65.535f;
  if (with_truth) {
    gpu::FaceParameters p = gpu::frontal_pose(0.8f);
    p.alpha = Eigen::VectorXf::LinSpaced(5, -0.01f, 0.02f);
    p.beta = Eigen::VectorXf::Constant(3, 0.125f);
    p.delta = Eigen::VectorXf::Zero(52);
    p.delta[17] = 0.375f;  // jawOpen... whatever index 17 is, it must survive by name
    p.delta[51] = 1.0f;
    p.gamma[4] = -0.3f;
    p.euler = Eigen::Vector3f(3.0f, 0.1f, -0.05f);
    p.translation = Eigen::Vector3f(0.01f, -0.02f, 0.8123f);
    f.ground_truth.params = p;
    std::array<LandmarkObservation, kNumLandmarks> l;
    for (int i = 0; i < kNumLandmarks; ++i) {
      l[static_cast<size_t>(i)].pixel = Eigen::Vector2f(0.1f * static_cast<float>(i), -3.25f + static_cast<float>(i));
      l[static_cast<size_t>(i)].visible = i % 3 != 0;
    }
    f.ground_truth.landmarks = l;
  }
  return f;
}

std::string write_recording(const TempDir& tmp, int frames = 3) {
  RecordingWriter w(tmp / "rec", small_info());
  for (int i = 0; i < frames; ++i) w.write(make_frame(i, i == 0));
  return w.finish();
}

TEST(CaptureRecordingTest, RoundTripIsExact) {
  TempDir tmp;
  const std::string dir = write_recording(tmp);
  EXPECT_EQ(dir, tmp / "rec");
  RecordingReader r(dir);
  ASSERT_EQ(r.frame_count(), 3);
  const RecordingInfo& info = r.info();
  EXPECT_EQ(info.camera.width, kW);
  EXPECT_EQ(info.camera.height, kH);
  EXPECT_EQ(info.camera.fx, 40.5f);
  EXPECT_EQ(info.camera.fy, 41.25f);
  EXPECT_EQ(info.camera.cx, 15.75f);
  EXPECT_EQ(info.camera.cy, 11.5f);
  EXPECT_EQ(info.fps, 25);
  EXPECT_EQ(info.depth_scale, 0.001);
  EXPECT_EQ(info.source, "unit test");
  for (int i = 0; i < 3; ++i) {
    const RgbdFrame expected = make_frame(i, i == 0);
    const RgbdFrame got = r.read(i);
    EXPECT_EQ(got.index, i);
    EXPECT_DOUBLE_EQ(got.timestamp_s, expected.timestamp_s);
    ASSERT_EQ(got.color.type(), CV_8UC3);
    EXPECT_EQ(cv::norm(got.color, expected.color, cv::NORM_INF), 0.0);
    ASSERT_EQ(got.depth.type(), CV_32FC1);
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x) {
        const float z = expected.depth.at<float>(y, x);
        const long want_mm = std::isfinite(z) && z > 0 && std::lround(z * 1000.0) <= 65535 ? std::lround(z * 1000.0) : 0;
        // 16-bit exactness: the stored millimetres come back unchanged.
        ASSERT_EQ(std::lround(got.depth.at<float>(y, x) * 1000.0), want_mm) << "pixel " << x << "," << y;
      }
    EXPECT_EQ(got.ground_truth.params.has_value(), i == 0);
    EXPECT_EQ(got.ground_truth.landmarks.has_value(), i == 0);
  }
  const RgbdFrame f0 = r.read(0);
  const RgbdFrame reference = make_frame(0, true);
  const gpu::FaceParameters& want = *reference.ground_truth.params;
  const gpu::FaceParameters& got = *f0.ground_truth.params;
  EXPECT_EQ(got.alpha, want.alpha);
  EXPECT_EQ(got.beta, want.beta);
  EXPECT_EQ(got.delta, want.delta);
  EXPECT_EQ(got.gamma, want.gamma);
  EXPECT_EQ(got.euler, want.euler);
  EXPECT_EQ(got.translation, want.translation);
  const auto& wl = *reference.ground_truth.landmarks;
  const auto& gl = *f0.ground_truth.landmarks;
  for (int i = 0; i < kNumLandmarks; ++i) {
    EXPECT_EQ(gl[static_cast<size_t>(i)].pixel, wl[static_cast<size_t>(i)].pixel);
    EXPECT_EQ(gl[static_cast<size_t>(i)].visible, wl[static_cast<size_t>(i)].visible);
  }
  // Sequential reading yields the same frames and then stops.
  RgbdFrame f;
  int n = 0;
  while (r.read_next(&f)) ++n;
  EXPECT_EQ(n, 3);
  EXPECT_THROW(r.read(3), Error);
  EXPECT_THROW(r.read(-1), Error);
}

// A still held for a performance (`reenact --target photo.jpg`): the same picture, frame after
// frame, with indices and timestamps counting up at the given rate; bad arguments are errors.
TEST(CaptureHeldFrameSourceTest, RepeatsTheStillWithTimesCountingUp) {
  RgbdFrame still;
  still.color = cv::Mat(6, 8, CV_8UC3, cv::Scalar(10, 20, 30));
  still.index = 7;
  RecordingInfo info;
  info.has_depth = false;
  HeldFrameSource held(still, info, 3, 25.0);
  EXPECT_EQ(held.info().frame_count, 3);
  EXPECT_DOUBLE_EQ(held.info().fps, 25.0);
  RgbdFrame f;
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(held.read_next(&f));
    EXPECT_EQ(f.index, i);
    EXPECT_DOUBLE_EQ(f.timestamp_s, i / 25.0);
    EXPECT_EQ(cv::norm(f.color, still.color, cv::NORM_INF), 0.0);
    f.color.setTo(cv::Scalar(0, 0, 0));  // a reader drawing on its frame does not change the next
  }
  EXPECT_FALSE(held.read_next(&f));
  EXPECT_THROW(HeldFrameSource(still, info, 0, 25.0), Error);
  EXPECT_THROW(HeldFrameSource(still, info, 3, 0.0), Error);
  EXPECT_THROW(HeldFrameSource(RgbdFrame{}, info, 3, 25.0), Error);
}

TEST(CaptureRecordingTest, ExpressionsAreStoredByArkitName) {
  TempDir tmp;
  const std::string dir = write_recording(tmp, 1);
  const std::string lines = slurp(dir + "/frames.jsonl");
  EXPECT_NE(lines.find("\"jawOpen\""), std::string::npos);
  EXPECT_NE(lines.find("\"tongueOut\":1.0"), std::string::npos);
}

TEST(CaptureRecordingTest, RgbOnlyRecording) {
  TempDir tmp;
  RecordingInfo info = small_info();
  info.has_depth = false;
  RecordingWriter w(tmp / "rgb", info);
  RgbdFrame f = make_frame(0, false);
  f.depth = cv::Mat();
  w.write(f);
  w.finish();
  RecordingReader r(tmp / "rgb");
  EXPECT_FALSE(r.info().has_depth);
  EXPECT_TRUE(r.read(0).depth.empty());
  EXPECT_FALSE(fs::exists(tmp / "rgb/depth"));
}

TEST(CaptureRecordingWriterTest, RefusesBadTargetsAndFrames) {
  TempDir tmp;
  EXPECT_THROW_WITH(RecordingWriter(tmp / "missing/parent/rec", small_info()), "does not exist");
  spit(tmp / "file", "x");
  EXPECT_THROW_WITH(RecordingWriter(tmp / "file/rec", small_info()), "does not exist");
  fs::create_directory(tmp / "exists");
  EXPECT_THROW_WITH(RecordingWriter(tmp / "exists", small_info()), "already exists");
  RecordingInfo bad = small_info();
  bad.fps = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW_WITH(RecordingWriter(tmp / "bad", bad), "fps");
  bad = small_info();
  bad.camera.fx = -1;
  EXPECT_THROW(RecordingWriter(tmp / "bad", bad), Error);

  RecordingWriter w(tmp / "rec", small_info());
  RgbdFrame f = make_frame(1, false);
  EXPECT_THROW_WITH(w.write(f), "out of order");
  f = make_frame(0, false);
  f.color = cv::Mat(kH, kW + 1, CV_8UC3, cv::Scalar(0));
  EXPECT_THROW_WITH(w.write(f), "colour");
  f = make_frame(0, false);
  f.depth = cv::Mat(kH, kW, CV_16UC1, cv::Scalar(0));
  EXPECT_THROW_WITH(w.write(f), "depth");
  f = make_frame(0, true);
  f.ground_truth.params->translation.z() = std::numeric_limits<float>::infinity();
  EXPECT_THROW_WITH(w.write(f), "ground truth");
}

TEST(CaptureRecordingWriterTest, UnfinishedRecordingLeavesNothingThatLooksComplete) {
  TempDir tmp;
  std::string partial;
  {
    RecordingWriter w(tmp / "rec", small_info());
    w.write(make_frame(0, false));
    partial = w.partial_dir();
    EXPECT_TRUE(fs::exists(partial));
    EXPECT_FALSE(fs::exists(tmp / "rec"));
  }
  EXPECT_FALSE(fs::exists(tmp / "rec"));
  EXPECT_FALSE(fs::exists(partial));
}

TEST(CaptureRecordingWriterTest, OverwriteReplacesOnlyWhenComplete) {
  TempDir tmp;
  write_recording(tmp, 3);
  RecordingWriter::Options o;
  o.overwrite = true;
  {
    RecordingWriter w(tmp / "rec", small_info(), o);
    w.write(make_frame(0, false));
    // Abandoned: the old recording must survive.
  }
  EXPECT_EQ(RecordingReader(tmp / "rec").frame_count(), 3);
  RecordingWriter w(tmp / "rec", small_info(), o);
  w.write(make_frame(0, false));
  w.finish();
  EXPECT_EQ(RecordingReader(tmp / "rec").frame_count(), 1);
}

TEST(CaptureRecordingReaderTest, MissingPiecesAreNamed) {
  TempDir tmp;
  EXPECT_THROW_WITH(RecordingReader(tmp / "nothing"), "not a folder");
  std::string dir = write_recording(tmp);
  fs::remove(dir + "/depth/000001.png");
  EXPECT_THROW_WITH(RecordingReader{dir}, "frame 1", "depth/000001.png", "missing");
  fs::remove_all(dir);
  dir = write_recording(tmp);
  fs::remove(dir + "/recording.json");
  EXPECT_THROW_WITH(RecordingReader{dir}, "no recording.json");
  fs::remove_all(dir);
  dir = write_recording(tmp);
  fs::remove(dir + "/frames.jsonl");
  EXPECT_THROW_WITH(RecordingReader{dir}, "frames.jsonl is missing");
}

TEST(CaptureRecordingReaderTest, MissingFrameLineIsAnError) {
  TempDir tmp;
  const std::string dir = write_recording(tmp);
  std::string lines = slurp(dir + "/frames.jsonl");
  const size_t a = lines.find('\n'), b = lines.find('\n', a + 1);
  spit(dir + "/frames.jsonl", lines.substr(0, a + 1) + lines.substr(b + 1));  // drop frame 1
  EXPECT_THROW_WITH(RecordingReader{dir}, "frames.jsonl line 2", "expected frame 1, got 2");
}

TEST(CaptureRecordingReaderTest, TruncatedPngIsAnError) {
  TempDir tmp;
  const std::string dir = write_recording(tmp);
  const std::string png = slurp(dir + "/color/000002.png");
  spit(dir + "/color/000002.png", png.substr(0, png.size() / 2));
  RecordingReader r(dir);
  EXPECT_NO_THROW(r.read(1));
  EXPECT_THROW_WITH(r.read(2), "frame 2", "color/000002.png", "cannot decode");
  const std::string dpng = slurp(dir + "/depth/000001.png");
  spit(dir + "/depth/000001.png", dpng.substr(0, 20));
  EXPECT_THROW_WITH(r.read(1), "frame 1", "depth/000001.png");
}

TEST(CaptureRecordingReaderTest, EightBitDepthIsAnError) {
  TempDir tmp;
  const std::string dir = write_recording(tmp);
  cv::imwrite(dir + "/depth/000000.png", cv::Mat(kH, kW, CV_8UC1, cv::Scalar(100)));
  RecordingReader r(dir);
  EXPECT_THROW_WITH(r.read(0), "depth/000000.png", "16-bit", "8-bit");
}

TEST(CaptureRecordingReaderTest, WrongImageSizeIsAnError) {
  TempDir tmp;
  const std::string dir = write_recording(tmp);
  cv::imwrite(dir + "/depth/000000.png", cv::Mat(kH, kW * 2, CV_16UC1, cv::Scalar(100)));
  cv::imwrite(dir + "/color/000001.png", cv::Mat(kH + 1, kW, CV_8UC3, cv::Scalar(1, 2, 3)));
  cv::imwrite(dir + "/color/000002.png", cv::Mat(kH, kW, CV_16UC3, cv::Scalar(1, 2, 3)));
  RecordingReader r(dir);
  EXPECT_THROW_WITH(r.read(0), "depth/000000.png", "64x24");
  EXPECT_THROW_WITH(r.read(1), "color/000001.png", "32x25");
  EXPECT_THROW_WITH(r.read(2), "color/000002.png", "8 bits");
}

TEST(CaptureRecordingReaderTest, BadJsonValuesAreNamedByKeyPath) {
  struct Case {
    const char* file;
    const char* from;
    const char* to;
    std::vector<const char*> expect;
  };
  const std::vector<Case> cases = {
      {"frames.jsonl", "\"timestamp\":0.0", "\"timestamp\":NaN", {"frames.jsonl line 1", "invalid JSON"}},
      {"frames.jsonl", "\"timestamp\":0.04", "\"timestamp\":null", {"line 2", "timestamp", "null"}},
      {"frames.jsonl", "\"timestamp\":0.04", "\"timestmap\":0.04", {"line 2", "timestmap", "unknown key"}},
      {"frames.jsonl", "\"timestamp\":0.04", "\"timestamp\":-1", {"line 2", "timestamp", "out of range"}},
      {"frames.jsonl", "\"jawOpen\"", "\"jawOpn\"", {"line 1", "ground_truth.params.delta.jawOpn", "unknown ARKit"}},
      {"frames.jsonl", "\"tongueOut\":1.0", "\"tongueOut\":1.5", {"ground_truth.params.delta.tongueOut", "out of range"}},
      {"frames.jsonl", "\"translation\":[", "\"translation\":[\"x\",", {"ground_truth.params.translation"}},
      {"frames.jsonl", "\"landmarks\":[[", "\"landmarks\":[[0,0,true],[", {"ground_truth.landmarks", "68"}},
      {"frames.jsonl", "\"color\":\"color/000001.png\"", "\"color\":\"../x.png\"", {"line 2", "color", "relative"}},
      {"recording.json", "\"fps\": 25.0", "\"fps\": 0", {"recording.json", "fps", "out of range"}},
      {"recording.json", "\"fps\": 25.0", "\"fps\": 25.0, \"colour\": 1", {"recording.json", "colour", "unknown key"}},
      {"recording.json", "\"fx\": 40.5", "\"fx\": \"40.5\"", {"recording.json", "camera.fx", "expected a number"}},
      {"recording.json", "\"width\": 32", "\"width\": 32.5", {"camera.width", "integer"}},
      {"recording.json", "\"version\": 1", "\"version\": 2", {"version", "unsupported"}},
      {"recording.json", "\"frame_count\": 3", "\"frame_count\": 4", {"says 4 frames", "lists 3"}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(std::string(c.file) + ": " + c.to);
    TempDir tmp;
    const std::string dir = write_recording(tmp);
    replace_in_file(dir + "/" + c.file, c.from, c.to);
    bool thrown = false;
    try {
      RecordingReader r(dir);
    } catch (const Error& e) {
      thrown = true;
      for (const char* part : c.expect)
        EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << "message: " << e.what() << " lacks " << part;
    }
    EXPECT_TRUE(thrown);
  }
}

TEST(CaptureGroundTruthJsonTest, AcceptsArkitOrderArrays) {
  const GroundTruth t = ground_truth_from_json(
      R"({"params":{"alpha":[],"beta":[0.5],"delta":[0,0.25],"gamma":[1,0,0,0,0,0,0,0,0,1,0,0,0,0,0,0,0,0,1,0,0,0,0,0,0,0,0],)"
      R"("euler":[3.14,0,0],"translation":[0,0,1]}})",
      "test");
  ASSERT_TRUE(t.params);
  EXPECT_FALSE(t.landmarks);
  EXPECT_EQ(t.params->delta.size(), 2);
  EXPECT_FLOAT_EQ(t.params->delta[1], 0.25f);
  EXPECT_THROW_WITH(ground_truth_from_json(R"({"params":{}})", "gt"), "gt", "params.alpha", "missing");
  EXPECT_THROW_WITH(ground_truth_from_json(R"({"extra":1})", "gt"), "extra", "unknown key");
  EXPECT_THROW_WITH(ground_truth_from_json("{", "gt"), "gt", "invalid JSON");
}

TEST(CaptureCameraTest, FromFieldOfView) {
  const gpu::PinholeCamera c = camera_from_fov(640, 480, 60.0);
  EXPECT_NEAR(c.fx, 320.0 / std::tan(M_PI / 6), 1e-3);
  EXPECT_EQ(c.fx, c.fy);
  EXPECT_FLOAT_EQ(c.cx, 319.5f);
  EXPECT_FLOAT_EQ(c.cy, 239.5f);
  EXPECT_THROW(camera_from_fov(640, 480, 0.0), Error);
  EXPECT_THROW(camera_from_fov(0, 480, 60.0), Error);
}

std::string shared_data() {
  const char* d = std::getenv("FR_SHARED_DATA");
  return d && fs::is_directory(d) ? d : "";
}

TEST(CaptureVideoReaderTest, ReadsVideoFilesAsRgbOnlyRecordings) {
  const std::string data = shared_data();
  if (data.empty()) GTEST_SKIP() << "FR_SHARED_DATA not set or missing: no real videos to read";
  for (const char* name : {"videos/webcam_talking_640x480.wmv", "videos/multi_face.avi", "videos/liveportrait_d0.mp4"}) {
    SCOPED_TRACE(name);
    auto source = open_frame_source(data + "/" + name);
    const RecordingInfo& info = source->info();
    EXPECT_FALSE(info.has_depth);
    EXPECT_GT(info.fps, 0);
    EXPECT_NEAR(info.camera.fx, 0.5 * info.camera.width / std::tan(M_PI / 6), 1e-2);
    RgbdFrame f;
    for (int i = 0; i < 3; ++i) {
      ASSERT_TRUE(source->read_next(&f));
      EXPECT_EQ(f.index, i);
      EXPECT_EQ(f.color.type(), CV_8UC3);
      EXPECT_EQ(f.color.cols, info.camera.width);
      EXPECT_EQ(f.color.rows, info.camera.height);
      EXPECT_TRUE(f.depth.empty());
      EXPECT_GT(cv::norm(f.color, cv::NORM_L1), 0.0);  // not a black frame
    }
  }
  VideoReader webcam(data + "/videos/webcam_talking_640x480.wmv");
  EXPECT_EQ(webcam.info().camera.width, 640);
  EXPECT_EQ(webcam.info().camera.height, 480);
}

TEST(CaptureVideoReaderTest, BadFilesAreClearErrors) {
  TempDir tmp;
  EXPECT_THROW_WITH(open_frame_source(tmp / "absent.mp4"), "no such file");
  spit(tmp / "garbage.mp4", std::string(4096, 'x'));
  EXPECT_THROW_WITH(open_frame_source(tmp / "garbage.mp4"), "garbage.mp4", "cannot open");
  spit(tmp / "room.oni", "x");
  EXPECT_THROW_WITH(open_frame_source(tmp / "room.oni"), "room.oni", "openni:");  // capture has no OpenNI2: says what to give
  VideoReader::Options o;
  o.horizontal_fov_deg = 0;
  EXPECT_THROW_WITH(VideoReader(tmp / "garbage.mp4", o), "horizontal_fov_deg");
}

}  // namespace
}  // namespace face_reenact::capture
