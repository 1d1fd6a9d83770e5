// The detector on real faces and on bad input: every format, odd and tiny sizes, blur, faces
// cut by the frame, black and noise frames, broken models. Nothing may crash; every outcome
// has a status and a reason.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <filesystem>
#include <fstream>
#include <random>
#include <thread>

#include "face_reenact/common/error.h"
#include "face_reenact/landmarks/evaluation.h"
#include "dlib_backend.h"
#include "landmark_internal.h"
#include "face_reenact/landmarks/landmark_tracker.h"
#include "test_data.h"

namespace face_reenact::landmarks {
namespace {
using test::shared_detector;

cv::Mat as_mat(const Image& im) {
  return cv::Mat(im.height, im.width, CV_8UC3, const_cast<uint8_t*>(im.pixels.data())).clone();
}
ImageView view_of(const cv::Mat& m, PixelFormat f) {
  return ImageView{m.data, m.cols, m.rows, m.step[0], f};
}
float max_point_distance(const LandmarkResult& a, const LandmarkResult& b) {
  float d = 0;
  for (int i = 0; i < kNumLandmarks; ++i) d = std::max(d, (a.points[size_t(i)] - b.points[size_t(i)]).norm());
  return d;
}

class RealFaceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    FR_REQUIRE_MODEL();
    path_ = test::shared_path("faces-68/lfpw/image_0001.png");
    if (path_.empty()) GTEST_SKIP() << "real test data 'faces-68' not found: set FR_SHARED_DATA";
    image_ = load_image(path_);
    bgr_ = as_mat(image_);
    truth_ = read_pts(test::shared_path("faces-68/lfpw/image_0001.pts"));
    reference_ = shared_detector().Detect(image_.view());
    ASSERT_TRUE(reference_.ok()) << reference_.reason;
  }
  std::string path_;
  Image image_;
  cv::Mat bgr_;
  Shape68 truth_;
  LandmarkResult reference_;
};

TEST_F(RealFaceTest, FindsTheFaceAccurately) {
  EXPECT_EQ(reference_.source, LandmarkSource::kDetected);
  EXPECT_GE(reference_.faces_found, 1);
  EXPECT_LT(nme_outer_eye(reference_.points, truth_), 0.05f);
  EXPECT_GT(reference_.score, 0.3f);
  EXPECT_LT(reference_.shape_residual, shared_detector().options().max_shape_residual);
  for (int i = 0; i < kNumLandmarks; ++i) {
    EXPECT_TRUE(reference_.visible[size_t(i)]);
    EXPECT_GE(reference_.confidence[size_t(i)], 0.f);
    EXPECT_LE(reference_.confidence[size_t(i)], 1.f);
  }
  EXPECT_TRUE(is_silhouette_point(0) && is_silhouette_point(16) && !is_silhouette_point(17));
}

TEST_F(RealFaceTest, GreyBgraRgbAndStridedViewsGiveTheSamePoints) {
  cv::Mat gray, bgra, rgb;
  cv::cvtColor(bgr_, gray, cv::COLOR_BGR2GRAY);
  cv::cvtColor(bgr_, bgra, cv::COLOR_BGR2BGRA);
  cv::cvtColor(bgr_, rgb, cv::COLOR_BGR2RGB);
  // A padded buffer: rows longer than the image, as cameras and OBS deliver them.
  cv::Mat padded(bgr_.rows, bgr_.cols + 13, CV_8UC3, cv::Scalar(255, 0, 255));
  bgr_.copyTo(padded(cv::Rect(0, 0, bgr_.cols, bgr_.rows)));
  const ImageView padded_view{padded.data, bgr_.cols, bgr_.rows, padded.step[0], PixelFormat::kBGR8};
  for (const auto& [name, view] : {std::pair{"gray", view_of(gray, PixelFormat::kGray8)},
                                   std::pair{"bgra", view_of(bgra, PixelFormat::kBGRA8)},
                                   std::pair{"rgb", view_of(rgb, PixelFormat::kRGB8)},
                                   std::pair{"padded", padded_view}}) {
    const LandmarkResult r = shared_detector().Detect(view);
    ASSERT_TRUE(r.ok()) << name << ": " << r.reason;
    EXPECT_LT(max_point_distance(r, reference_), 1.0f) << name;
  }
}

TEST_F(RealFaceTest, OddSizedFrameWorks) {
  // The photo pasted into an odd-sized grey frame (odd width and height, odd row length).
  for (const cv::Size size : {cv::Size(641, 479), cv::Size(333, 517)}) {
    cv::Mat odd(size, CV_8UC3, cv::Scalar(90, 90, 90));
    const Eigen::Vector2f c = reference_.face_box.center();
    const cv::Point offset(size.width / 2 - int(c.x()), size.height / 2 - int(c.y()));
    const cv::Rect src = cv::Rect(-offset.x, -offset.y, size.width, size.height) & cv::Rect(0, 0, bgr_.cols, bgr_.rows);
    bgr_(src).copyTo(odd(cv::Rect(src.x + offset.x, src.y + offset.y, src.width, src.height)));
    const LandmarkResult r = shared_detector().Detect(view_of(odd, PixelFormat::kBGR8));
    ASSERT_TRUE(r.ok()) << size << ": " << r.reason;
    Shape68 moved = truth_;
    for (auto& p : moved) p += Eigen::Vector2f(float(offset.x), float(offset.y));
    EXPECT_LT(nme_outer_eye(r.points, moved), 0.05f) << size;
  }
}

TEST_F(RealFaceTest, BlurredFaceIsReported) {
  cv::Mat blurred;
  cv::GaussianBlur(bgr_, blurred, cv::Size(0, 0), reference_.face_box.width / 15.0);
  const LandmarkResult r = shared_detector().Detect(view_of(blurred, PixelFormat::kBGR8));
  EXPECT_TRUE(r.status == DetectionStatus::kBlurred || r.status == DetectionStatus::kNoFace)
      << status_name(r.status) << ": " << r.reason;
  EXPECT_FALSE(r.reason.empty());
}

TEST_F(RealFaceTest, FaceCutByTheFrameIsPartial) {
  // Keep the left 55% of the face box: the rest of the face is outside the frame.
  const Box& b = reference_.face_box;
  const int right = int(b.x + 0.55f * b.width);
  cv::Mat cut = bgr_(cv::Rect(0, 0, right, bgr_.rows)).clone();
  const LandmarkResult r = shared_detector().Detect(view_of(cut, PixelFormat::kBGR8));
  if (r.status == DetectionStatus::kNoFace) {
    EXPECT_NE(r.reason.find("no face"), std::string::npos);
    return;  // the detector may not see half a face; that is a valid, clear outcome
  }
  // Fitting from the known box shows what happens to the points outside.
  const LandmarkResult fit = shared_detector().FitFromBox(view_of(cut, PixelFormat::kBGR8), b);
  EXPECT_EQ(fit.status, DetectionStatus::kPartiallyOutside) << fit.reason;
  int invisible = 0;
  for (int i = 0; i < kNumLandmarks; ++i) {
    if (fit.points[size_t(i)].x() > float(cut.cols - 1)) {
      EXPECT_FALSE(fit.visible[size_t(i)]) << i;
      EXPECT_EQ(fit.confidence[size_t(i)], 0.f) << i;
      ++invisible;
    }
  }
  EXPECT_GT(invisible, 5);
}

TEST_F(RealFaceTest, TrackingHintStartsFromPreviousPoints) {
  TrackingHint hint;
  hint.previous_points = reference_.points;
  const LandmarkResult r = shared_detector().Detect(image_.view(), hint);
  ASSERT_TRUE(r.ok()) << r.reason;
  EXPECT_EQ(r.source, LandmarkSource::kTracked);
  EXPECT_LT(nme_outer_eye(r.points, truth_), 0.05f);
  // The re-centred box matches the detector's own box closely.
  const Box box = shared_detector().BoxFromPoints(reference_.points);
  EXPECT_GT(box.iou(reference_.face_box), 0.65f);
}

TEST_F(RealFaceTest, ImplausibleHintFallsBackToSearch) {
  TrackingHint hint;
  Shape68 garbage;
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(0.f, float(std::min(bgr_.cols, bgr_.rows)));
  for (auto& p : garbage) p = {u(rng), u(rng)};
  hint.previous_points = garbage;
  const LandmarkResult r = shared_detector().Detect(image_.view(), hint);
  ASSERT_TRUE(r.ok()) << r.reason;
  EXPECT_LT(nme_outer_eye(r.points, truth_), 0.05f);
}

TEST_F(RealFaceTest, PosePruningHidesTheFarSide) {
  const DetectorOptions& o = shared_detector().options();
  // Subject's left half is at larger x in this unmirrored photo.
  ASSERT_GT(reference_.points[45].x(), reference_.points[36].x());
  for (float yaw : {45.f, -45.f}) {
    LandmarkResult r = reference_;
    const int hidden = apply_pose_pruning(HeadPose{yaw, 0, 0}, o, &r);
    const int far = yaw > 0 ? +1 : -1;  // +yaw turns the +x half (subject's left) away
    int expected_hidden = 0;
    for (int i = 0; i < kNumLandmarks; ++i) {
      if (face_side(i) == far) {
        ++expected_hidden;
        EXPECT_FALSE(r.visible[size_t(i)]) << "yaw " << yaw << " point " << i;
        EXPECT_EQ(r.confidence[size_t(i)], 0.f);
      } else {
        EXPECT_TRUE(r.visible[size_t(i)]) << "yaw " << yaw << " point " << i;
        EXPECT_EQ(r.confidence[size_t(i)], reference_.confidence[size_t(i)]);
      }
    }
    EXPECT_EQ(hidden, expected_hidden);
    EXPECT_GT(hidden, 20);
  }
  // Moderate yaw: down-weighted, still visible. Small yaw: untouched.
  LandmarkResult r = reference_;
  EXPECT_EQ(apply_pose_pruning(HeadPose{22.f, 0, 0}, o, &r), 0);
  EXPECT_TRUE(r.visible[45]);
  EXPECT_LT(r.confidence[45], reference_.confidence[45]);
  EXPECT_EQ(r.confidence[36], reference_.confidence[36]);
  r = reference_;
  apply_pose_pruning(HeadPose{10.f, 0, 0}, o, &r);
  EXPECT_EQ(r.confidence, reference_.confidence);
}

TEST_F(RealFaceTest, PosePruningFollowsTheImageInMirroredFrames) {
  cv::Mat mirrored;
  cv::flip(bgr_, mirrored, 1);
  TrackingHint hint;
  hint.pose = HeadPose{45.f, 0, 0};
  const LandmarkResult r = shared_detector().Detect(view_of(mirrored, PixelFormat::kBGR8), hint);
  ASSERT_TRUE(r.has_landmarks) << r.reason;
  // Whatever iBUG half ends up at +x is the one turned away.
  const float cx = r.points[30].x();
  for (int i = 0; i < kNumLandmarks; ++i) {
    if (face_side(i) == 0) continue;
    const bool at_plus_x = (face_side(i) == +1) == (r.points[45].x() > r.points[36].x());
    EXPECT_EQ(r.visible[size_t(i)], !at_plus_x) << i << " x=" << r.points[size_t(i)].x() << " nose " << cx;
  }
}

TEST(DetectorInputTest, InvalidViewsAreRejectedWithReasons) {
  FR_REQUIRE_MODEL();
  std::vector<uint8_t> pixels(100 * 100 * 3, 128);
  const ImageView cases[] = {
      {nullptr, 100, 100, 0, PixelFormat::kBGR8},
      {pixels.data(), 0, 100, 0, PixelFormat::kBGR8},
      {pixels.data(), 100, -5, 0, PixelFormat::kBGR8},
      {pixels.data(), 100, 100, 200, PixelFormat::kBGR8},  // stride shorter than a row
      {pixels.data(), 40000, 1, 0, PixelFormat::kGray8},
  };
  for (const ImageView& v : cases) {
    const LandmarkResult r = shared_detector().Detect(v);
    EXPECT_EQ(r.status, DetectionStatus::kInvalidInput);
    EXPECT_FALSE(r.reason.empty());
    EXPECT_FALSE(r.has_landmarks);
    EXPECT_EQ(shared_detector().FitFromBox(v, Box{0, 0, 50, 50}).status, DetectionStatus::kInvalidInput);
    EXPECT_TRUE(shared_detector().FindFaces(v, true).empty());
  }
}

TEST(DetectorInputTest, TinyBlackAndNoiseFramesGiveAClearStatus) {
  FR_REQUIRE_MODEL();
  // Tiny: smaller than any usable face.
  cv::Mat tiny(30, 40, CV_8UC3, cv::Scalar(90, 120, 200));
  LandmarkResult r = shared_detector().Detect(view_of(tiny, PixelFormat::kBGR8));
  EXPECT_EQ(r.status, DetectionStatus::kFaceTooSmall) << r.reason;
  EXPECT_NE(r.reason.find("40x30"), std::string::npos) << r.reason;
  cv::Mat one(1, 1, CV_8UC1, cv::Scalar(0));
  EXPECT_EQ(shared_detector().Detect(view_of(one, PixelFormat::kGray8)).status, DetectionStatus::kFaceTooSmall);
  // Black and noise: no face, no crash.
  cv::Mat black(480, 640, CV_8UC3, cv::Scalar(0, 0, 0));
  r = shared_detector().Detect(view_of(black, PixelFormat::kBGR8));
  EXPECT_EQ(r.status, DetectionStatus::kNoFace);
  EXPECT_NE(r.reason.find("no face"), std::string::npos);
  cv::Mat noise(479, 641, CV_8UC3);
  cv::randu(noise, cv::Scalar::all(0), cv::Scalar::all(255));
  r = shared_detector().Detect(view_of(noise, PixelFormat::kBGR8));
  EXPECT_FALSE(r.ok()) << "a face in uniform noise";
  // Fitting onto a box of noise gives 68 points but flags them as implausible / unsure.
  const LandmarkResult fit = shared_detector().FitFromBox(view_of(noise, PixelFormat::kBGR8), Box{200, 150, 200, 200});
  ASSERT_TRUE(fit.has_landmarks);
  EXPECT_LT(fit.score, 0.5f);
}

TEST(DetectorInputTest, TinyFaceInALargerFrameIsNotOk) {
  FR_REQUIRE_MODEL();
  FR_REQUIRE_SHARED(path, "faces-68/lfpw/image_0001.png");
  const Image image = load_image(path);
  cv::Mat small;
  cv::resize(as_mat(image), small, cv::Size(), 0.08, 0.08, cv::INTER_AREA);  // face ~24 px
  cv::Mat frame(480, 640, CV_8UC3, cv::Scalar(60, 60, 60));
  small.copyTo(frame(cv::Rect(300, 200, small.cols, small.rows)));
  const LandmarkResult r = shared_detector().Detect(view_of(frame, PixelFormat::kBGR8));
  EXPECT_TRUE(r.status == DetectionStatus::kNoFace || r.status == DetectionStatus::kFaceTooSmall)
      << status_name(r.status) << " " << r.reason;
}

TEST(DetectorOptionsTest, RejectsBadOptions) {
  std::string error;
  EXPECT_TRUE(DetectorOptions{}.IsValid(&error)) << error;
  auto bad = [](auto mutate) {
    DetectorOptions o;
    mutate(o);
    std::string e;
    EXPECT_FALSE(o.IsValid(&e));
    EXPECT_FALSE(e.empty());
    EXPECT_THROW(LandmarkDetector{o}, Error);
  };
  bad([](DetectorOptions& o) { o.detection_width = 10; });
  bad([](DetectorOptions& o) { o.max_upsample = 7; });
  bad([](DetectorOptions& o) { o.confidence_samples = 0; });
  bad([](DetectorOptions& o) { o.confidence_samples = 10; });
  bad([](DetectorOptions& o) { o.jitter_fraction = 0; });
  bad([](DetectorOptions& o) { o.confidence_sigma = -1; });
  bad([](DetectorOptions& o) { o.max_outside_fraction = 2; });
  bad([](DetectorOptions& o) { o.prune_full_deg = 10; });
  bad([](DetectorOptions& o) { o.detector_threshold = std::nan(""); });
}

TEST(DetectorModelTest, MissingOrCorruptModelIsAClearError) {
  DetectorOptions o;
  o.shape_predictor_path = "/nonexistent/sp.dat";
  try {
    LandmarkDetector d(o);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/sp.dat"), std::string::npos);
  }
  const ::face_reenact::testing::TempDir dir("fr-landmarks-detector-test");
  const std::string corrupt = dir / "corrupt_sp.dat";
  {
    std::ofstream f(corrupt, std::ios::binary);
    f << "this is not a dlib model, just some bytes";
  }
  o.shape_predictor_path = corrupt;
  EXPECT_THROW(LandmarkDetector{o}, Error);
  std::filesystem::remove(corrupt);
}

// A model read ahead (PreloadShapeModel) is the one every detector made meanwhile takes, read once
// even when two threads ask at once, and the read holds no reference of its own: the model goes
// with its last detector, as one read by a detector does.
TEST(ShapeModelPreloadTest, DetectorsTakeTheModelReadAheadWhichGoesWithTheirs) {
  FR_REQUIRE_MODEL();
  const std::string path = internal::default_shape_predictor_path();
  if (detail::shape_model_in_memory(path))  // (CTest runs each test in a process of its own)
    GTEST_SKIP() << "another test of this process holds the model already";
  PreloadShapeModel();
  PreloadShapeModel();  // while it reads: nothing more
  std::shared_ptr<const detail::ShapeModel> here, there;
  std::thread other([&] { there = detail::load_shape_model(path); });
  here = detail::load_shape_model(path);
  other.join();
  ASSERT_TRUE(here && there);
  EXPECT_EQ(here.get(), there.get());
  PreloadShapeModel();  // in memory: nothing
  {
    LandmarkDetector detector;
    cv::Mat noise(240, 320, CV_8UC3);
    cv::randu(noise, 0, 256);
    const LandmarkResult r = detector.Detect(view_of(noise, PixelFormat::kBGR8));
    EXPECT_FALSE(r.reason.empty());
  }
  const std::weak_ptr<const detail::ShapeModel> weak = here;
  here.reset();
  there.reset();
  // The read's thread lets its copy go as it ends, a moment after handing the model over.
  for (int i = 0; i < 500 && !weak.expired(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  EXPECT_TRUE(weak.expired()) << "the preload kept the model";
  EXPECT_FALSE(detail::shape_model_in_memory(path));
}

// A model that cannot be read ahead (missing, not a model) fails in the detector made next, with
// the error it gives without the preload, and again in the one after.
TEST(ShapeModelPreloadTest, AReadAheadThatFailsFailsInTheDetector) {
  DetectorOptions o;
  o.shape_predictor_path = "/nonexistent/preloaded_sp.dat";
  PreloadShapeModel(o);
  for (int attempt = 0; attempt < 2; ++attempt) {
    try {
      LandmarkDetector d(o);
      FAIL() << "no error";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("/nonexistent/preloaded_sp.dat"), std::string::npos) << e.what();
    }
  }
  const ::face_reenact::testing::TempDir dir("fr-landmarks-preload-test");
  const std::string corrupt = dir / "corrupt_sp.dat";
  std::ofstream(corrupt, std::ios::binary) << "this is not a dlib model, just some bytes";
  o.shape_predictor_path = corrupt;
  PreloadShapeModel(o);
  EXPECT_THROW(LandmarkDetector{o}, Error);
  o.detection_width = -5;  // options the detector refuses: no read started, the detector says why
  PreloadShapeModel(o);
  EXPECT_THROW(LandmarkDetector{o}, Error);
}

// The face detector embedded at build time (its serialisation, read in 2 ms) is dlib's own,
// which get_frontal_face_detector() decodes from dlib's built-in model in about 350 ms: the same
// bytes, so the same faces are found.
TEST(DlibBackend, TheEmbeddedFaceDetectorIsDlibsOwn) {
  const std::string embedded = detail::EmbeddedFaceDetectorSerialization();
  const std::string decoded = detail::DecodedFaceDetectorSerialization();
  ASSERT_GT(decoded.size(), 100000u);  // five HOG filters
  EXPECT_EQ(embedded.size(), decoded.size());
  EXPECT_TRUE(embedded == decoded) << "the embedded detector differs from dlib's; rebuild fr_embed_face_detector";
}

TEST(BoxTest, OverlapAndOutsideFraction) {
  const Box a{0, 0, 10, 10}, b{5, 0, 10, 10}, empty{};
  EXPECT_NEAR(a.iou(b), 50.f / 150.f, 1e-6f);
  EXPECT_EQ(a.iou(empty), 0.f);
  EXPECT_EQ(a.fraction_outside(100, 100), 0.f);
  EXPECT_NEAR(Box({-5, 0, 10, 10}).fraction_outside(100, 100), 0.5f, 1e-6f);
  EXPECT_EQ(empty.fraction_outside(100, 100), 1.f);
}

// Video frames of 320x240 hold faces near the HOG detector's 80 px window (the demo's are that size):
// the tracker's full search retries 2x upsampled while the result stays within 640x480, and
// only then finds them. Options that forbid the retry do not, which shows the frame needs it.
TEST(TrackerSmallFrameTest, SmallFacesInSmallFramesAreFoundUpsampled) {
  FR_REQUIRE_MODEL();
  FR_REQUIRE_SHARED(path, "faces-68/lfpw/image_0001.png");
  const cv::Mat photo = as_mat(load_image(path));
  const LandmarkResult full = shared_detector().Detect(view_of(photo, PixelFormat::kBGR8));
  ASSERT_TRUE(full.ok()) << full.reason;
  // The face scaled to a 45 px detector box (below the 80 px window) in a grey 320x240 frame.
  const double scale = 45.0 / full.face_box.width;
  cv::Mat small;
  cv::resize(photo, small, cv::Size(), scale, scale, cv::INTER_AREA);
  const cv::Point centre(int((full.face_box.x + 0.5f * full.face_box.width) * scale),
                         int((full.face_box.y + 0.5f * full.face_box.height) * scale));
  cv::Mat frame(240, 320, CV_8UC3, cv::Scalar(128, 128, 128));
  const cv::Rect from = cv::Rect(centre.x - 80, centre.y - 60, 160, 120) & cv::Rect(0, 0, small.cols, small.rows);
  small(from).copyTo(frame(cv::Rect(160 - (centre.x - from.x), 120 - (centre.y - from.y), from.width, from.height)));

  const TrackerOptions defaults;
  EXPECT_EQ(defaults.detector.max_upsample, 1);
  EXPECT_LE(defaults.detector.max_search_pixels, 640 * 480);  // a 640x480 frame is never upsampled
  LandmarkTracker tracker(defaults);
  const LandmarkResult found = tracker.Track(view_of(frame, PixelFormat::kBGR8), 0.0);
  EXPECT_TRUE(found.ok()) << found.reason;
  EXPECT_NEAR(found.face_box.width, 45.f, 20.f);

  TrackerOptions no_retry = defaults;
  no_retry.detector.max_upsample = 0;
  LandmarkTracker without(no_retry);
  EXPECT_FALSE(without.Track(view_of(frame, PixelFormat::kBGR8), 0.0).ok());
}

}  // namespace
}  // namespace face_reenact::landmarks

namespace face_reenact::landmarks {
namespace {

TEST(DetectorInputTest, AbsurdStartBoxesAndHintsAreHandled) {
  FR_REQUIRE_MODEL();
  std::vector<uint8_t> gray(320 * 240, 100);
  const ImageView view{gray.data(), 320, 240, 0, PixelFormat::kGray8};
  const float inf = std::numeric_limits<float>::infinity(), nan = std::nanf("");
  for (const Box& b : {Box{0, 0, 0, 0}, Box{nan, 0, 50, 50}, Box{0, 0, inf, 50}, Box{1e30f, 1e30f, 50, 50},
                       Box{-1e12f, 0, 1e13f, 1e13f}, Box{10, 10, -40, 40}}) {
    const LandmarkResult r = test::shared_detector().FitFromBox(view, b);
    EXPECT_EQ(r.status, DetectionStatus::kNoFace);
    EXPECT_FALSE(r.has_landmarks);
  }
  TrackingHint hint;
  Shape68 bad;
  bad.fill(Eigen::Vector2f(nan, nan));
  hint.previous_points = bad;
  hint.previous_box = Box{nan, nan, nan, nan};
  hint.pose = HeadPose{nan, nan, nan};
  const LandmarkResult r = test::shared_detector().Detect(view, hint);
  EXPECT_EQ(r.status, DetectionStatus::kNoFace) << r.reason;
}

}  // namespace
}  // namespace face_reenact::landmarks
