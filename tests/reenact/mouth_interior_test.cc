// The mouth interior of Sec. 7.4.1 (mouth_interior.h): mean-value coordinates, the warp of the
// actor's open-mouth still into another opening, the choice of the still, and the compositor and
// pipeline drawing it; the source actor's mouth standing in for a target that has not opened its
// own; the teeth proxy's texture (teeth_texture.h).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <tuple>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/common/srgb.h"
#include "face_reenact/reenact/face_compositor.h"
#include "face_reenact/reenact/mouth_interior.h"
#include "face_reenact/reenact/reenactment_pipeline.h"
#include "face_reenact/reenact/teeth_texture.h"
#include "face_reenact/reenact/transfer.h"
#include "reenact_test_support.h"

namespace face_reenact::reenact {
namespace {

using testing::render_target;
using testing::test_camera;
using testing::test_face;
using testing::albedo_map_options;
using testing::test_model;
using testing::pixel_polygon;

// An inner-lip-like octagon (iBUG 60-67 order: left corner, upper lip to the right corner, lower
// lip back), made non-convex by a dent in the upper lip's middle (a philtrum's dip).
std::vector<Eigen::Vector2f> lip_polygon() {
  return {{10.f, 20.f}, {20.f, 14.f}, {30.f, 17.f}, {40.f, 14.f}, {50.f, 20.f}, {40.f, 28.f}, {30.f, 30.f}, {20.f, 28.f}};
}

bool inside(const std::vector<Eigen::Vector2f>& poly, const Eigen::Vector2f& p) {
  std::vector<cv::Point2f> c;
  for (const auto& v : poly) c.emplace_back(v.x(), v.y());
  return cv::pointPolygonTest(c, cv::Point2f(p.x(), p.y()), false) > 0;
}

TEST(MouthInteriorTest, MeanValueCoordinatesReproduceEveryPointAndEveryVertex) {
  const std::vector<Eigen::Vector2f> poly = lip_polygon();
  std::vector<float> w;
  // Each vertex: its indicator (the warp carries the landmarks exactly).
  for (size_t k = 0; k < poly.size(); ++k) {
    ASSERT_TRUE(MeanValueCoordinates(poly, poly[k], &w));
    for (size_t i = 0; i < poly.size(); ++i) EXPECT_EQ(w[i], i == k ? 1.f : 0.f) << "vertex " << k;
  }
  // An edge's point: the interpolation of its ends.
  ASSERT_TRUE(MeanValueCoordinates(poly, 0.25f * poly[2] + 0.75f * poly[3], &w));
  EXPECT_NEAR(w[2], 0.25f, 1e-5f);
  EXPECT_NEAR(w[3], 0.75f, 1e-5f);
  // Inside (the dent included, where a convex-only formula goes wrong): weights sum to 1 and
  // reproduce the point.
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> x(10.f, 50.f), y(14.f, 30.f);
  int tested = 0;
  for (int k = 0; k < 2000 && tested < 300; ++k) {
    const Eigen::Vector2f p(x(rng), y(rng));
    if (!inside(poly, p)) continue;
    ++tested;
    ASSERT_TRUE(MeanValueCoordinates(poly, p, &w)) << p.transpose();
    float sum = 0.f;
    Eigen::Vector2f q = Eigen::Vector2f::Zero();
    for (size_t i = 0; i < poly.size(); ++i) {
      sum += w[i];
      q += w[i] * poly[i];
    }
    EXPECT_NEAR(sum, 1.f, 1e-5f);
    EXPECT_LT((q - p).norm(), 1e-3f) << p.transpose();
  }
  EXPECT_GE(tested, 300);
  // Either orientation.
  std::vector<Eigen::Vector2f> reversed(poly.rbegin(), poly.rend());
  ASSERT_TRUE(MeanValueCoordinates(reversed, Eigen::Vector2f(30.f, 22.f), &w));
  Eigen::Vector2f q = Eigen::Vector2f::Zero();
  for (size_t i = 0; i < reversed.size(); ++i) q += w[i] * reversed[i];
  EXPECT_LT((q - Eigen::Vector2f(30.f, 22.f)).norm(), 1e-3f);
}

TEST(MouthInteriorTest, MeanValueCoordinatesRefuseDegenerateInput) {
  std::vector<float> w = {42.f};
  EXPECT_FALSE(MeanValueCoordinates({{0.f, 0.f}, {1.f, 1.f}}, {0.5f, 0.2f}, &w));
  EXPECT_FALSE(MeanValueCoordinates({{0.f, 0.f}, {1.f, 1.f}, {2.f, 2.f}}, {0.5f, 0.2f}, &w)) << "zero area";
  EXPECT_FALSE(MeanValueCoordinates(lip_polygon(), {std::nanf(""), 20.f}, &w));
  std::vector<Eigen::Vector2f> bad = lip_polygon();
  bad[3].x() = std::numeric_limits<float>::infinity();
  EXPECT_FALSE(MeanValueCoordinates(bad, {30.f, 22.f}, &w));
  EXPECT_EQ(w, std::vector<float>{42.f}) << "untouched on failure";
  EXPECT_DOUBLE_EQ(PolygonArea({{0.f, 0.f}, {4.f, 0.f}, {4.f, 3.f}, {0.f, 3.f}}), 12.0);
}

// An exemplar whose colour encodes the position: red = x, green = y (sRGB bytes).
MouthExemplar position_coded_exemplar(std::vector<Eigen::Vector2f> opening) {
  cv::Mat frame(60, 80, CV_8UC3);
  for (int j = 0; j < frame.rows; ++j)
    for (int i = 0; i < frame.cols; ++i) frame.at<cv::Vec3b>(j, i) = cv::Vec3b(40, static_cast<uchar>(3 * j), static_cast<uchar>(3 * i));
  return CaptureMouthExemplar(frame, opening, 0.5f, 12);
}

TEST(MouthInteriorTest, TheWarpCarriesTheLandmarksExactlyAndAnAffineOpeningAlong) {
  const std::vector<Eigen::Vector2f> poly = lip_polygon();
  const MouthExemplar e = position_coded_exemplar(poly);
  ASSERT_FALSE(e.empty());
  EXPECT_EQ(e.frame_index, 12);
  EXPECT_NEAR(e.area_px, PolygonArea(poly), 1e-9);
  // The crop keeps the opening with its margin; the polygon moves with it.
  EXPECT_LE(e.bgr.cols, 40 + 2 * 3 + 1);
  EXPECT_LE(e.bgr.rows, 16 + 2 * 3 + 1);
  // The output opening: the same mouth opened 1.6x taller, 1.2x wider and moved (an affine map).
  auto affine = [](const Eigen::Vector2f& v) { return Eigen::Vector2f(1.2f * v.x() + 100.f, 1.6f * v.y() + 40.f); };
  std::vector<Eigen::Vector2f> out;
  for (const auto& v : poly) out.push_back(affine(v));
  Eigen::Vector3f rgb;
  Eigen::Vector2f q;
  // Each output landmark samples exactly its exemplar landmark.
  for (size_t k = 0; k < out.size(); ++k) {
    ASSERT_TRUE(SampleMouthExemplar(e, out, out[k], &rgb, &q));
    EXPECT_LT((q - e.opening[k]).norm(), 1e-5f) << "landmark " << k;
  }
  // Inside, the map is the inverse affine map exactly (mean-value coordinates reproduce affine
  // functions), and the colour read there is the frame's at that place.
  const Eigen::Vector2f p = affine(Eigen::Vector2f(27.f, 23.f));
  ASSERT_TRUE(SampleMouthExemplar(e, out, p, &rgb, &q));
  const Eigen::Vector2f frame_point = q + (poly[0] - e.opening[0]);
  EXPECT_LT((frame_point - Eigen::Vector2f(27.f, 23.f)).norm(), 1e-3f);
  EXPECT_NEAR(255.f * srgb_encode(rgb[0]), 3.f * 27.f, 0.6f) << "red codes x";
  EXPECT_NEAR(255.f * srgb_encode(rgb[1]), 3.f * 23.f, 0.6f) << "green codes y";
  // Another vertex count is refused.
  out.pop_back();
  EXPECT_FALSE(SampleMouthExemplar(e, out, p, &rgb));
  EXPECT_FALSE(SampleMouthExemplar(MouthExemplar{}, poly, {30.f, 22.f}, &rgb));
}

TEST(MouthInteriorTest, CaptureRefusesOpeningsCutByTheFrameOrDegenerate) {
  cv::Mat frame(60, 80, CV_8UC3, cv::Scalar(1, 2, 3));
  std::vector<Eigen::Vector2f> poly = lip_polygon();
  EXPECT_FALSE(CaptureMouthExemplar(frame, poly, 0.5f, 0).empty());
  for (auto& v : poly) v.x() += 35.f;  // the right corner at x = 85, past the frame
  EXPECT_TRUE(CaptureMouthExemplar(frame, poly, 0.5f, 0).empty());
  EXPECT_TRUE(CaptureMouthExemplar(frame, {{1.f, 1.f}, {2.f, 2.f}, {3.f, 3.f}}, 0.5f, 0).empty());
  EXPECT_TRUE(CaptureMouthExemplar(cv::Mat(), lip_polygon(), 0.5f, 0).empty());
  EXPECT_TRUE(CaptureMouthExemplar(cv::Mat(60, 80, CV_8UC1), lip_polygon(), 0.5f, 0).empty());
}

TEST(MouthInteriorTest, TheStillIsAWideFrontalOpeningAndOnlyAClearlyWiderOneReplacesIt) {
  MouthExemplarOptions o;
  std::string why;
  ASSERT_TRUE(o.IsValid(&why)) << why;
  const std::vector<Eigen::Vector2f> poly = lip_polygon();  // area 400 px
  const MouthExemplar none;
  EXPECT_TRUE(IsBetterMouthExemplar(none, poly, 0.4f, 10.f, o));
  EXPECT_FALSE(IsBetterMouthExemplar(none, poly, 0.1f, 10.f, o)) << "barely open";
  EXPECT_FALSE(IsBetterMouthExemplar(none, poly, 0.4f, 35.f, o)) << "turned away";
  EXPECT_FALSE(IsBetterMouthExemplar(none, poly, std::nanf(""), 10.f, o));
  std::vector<Eigen::Vector2f> slit;
  for (const auto& v : poly) slit.emplace_back(v.x(), 22.f + 0.1f * (v.y() - 22.f));  // 40 px
  EXPECT_FALSE(IsBetterMouthExemplar(none, slit, 0.4f, 10.f, o)) << "too small an opening";
  const MouthExemplar current = CaptureMouthExemplar(cv::Mat(60, 80, CV_8UC3, cv::Scalar::all(9)), poly, 0.4f, 3);
  ASSERT_FALSE(current.empty());
  std::vector<Eigen::Vector2f> wider, slightly;
  for (const auto& v : poly) {
    wider.emplace_back(v.x(), 22.f + 1.4f * (v.y() - 22.f));
    slightly.emplace_back(v.x(), 22.f + 1.1f * (v.y() - 22.f));
  }
  EXPECT_TRUE(IsBetterMouthExemplar(current, wider, 0.6f, 5.f, o));
  EXPECT_FALSE(IsBetterMouthExemplar(current, slightly, 0.6f, 5.f, o)) << "a still that flickers";
  o.replace_area_ratio = 0.5;
  EXPECT_FALSE(o.IsValid(&why));
  o = MouthExemplarOptions{};
  o.margin_px = 0;
  EXPECT_FALSE(o.IsValid(&why));
}

TEST(MouthInteriorTest, BrightnessFollowsTheOpening) {
  EXPECT_FLOAT_EQ(MouthInteriorBrightness(500.0, 400.0), 1.f);
  EXPECT_FLOAT_EQ(MouthInteriorBrightness(400.0, 400.0), 1.f);
  EXPECT_NEAR(MouthInteriorBrightness(100.0, 400.0), 0.5f, 1e-6f);
  EXPECT_FLOAT_EQ(MouthInteriorBrightness(1.0, 400.0), 0.35f);
  EXPECT_FLOAT_EQ(MouthInteriorBrightness(100.0, 0.0), 1.f);
}

// A still of the actor's open mouth (`wide`): its frame with the opening painted green (the teeth
// and cavity a camera would see there), and the inside of its lips, just past the opening, the
// same green (the still's crop keeps 3 px around it).
MouthExemplar green_still(const FaceCompositor& fc, const gpu::PinholeCamera& cam, const gpu::FaceParameters& wide) {
  const std::vector<Eigen::Vector2f> wide_opening = fc.MouthOpening(cam, wide);
  if (wide_opening.size() != 8u) return {};
  cv::Mat still = render_target(wide, cam);
  const std::vector<cv::Point> poly = pixel_polygon(wide_opening);
  cv::fillPoly(still, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(40, 200, 40));
  cv::polylines(still, std::vector<std::vector<cv::Point>>{poly}, true, cv::Scalar(40, 200, 40), 7);
  return CaptureMouthExemplar(still, wide_opening, wide.delta[kJawOpenIndex], 0);
}

bool is_green(const cv::Vec3b& px) { return px[1] > px[0] + 40 && px[1] > px[2] + 40; }

// The green pixels of a whole 8-bit BGR image, and their mean green.
int count_green(const cv::Mat& bgr, double* mean_green = nullptr) {
  int n = 0;
  double sum = 0;
  for (int j = 0; j < bgr.rows; ++j)
    for (int i = 0; i < bgr.cols; ++i) {
      const cv::Vec3b px = bgr.at<cv::Vec3b>(j, i);
      if (!is_green(px)) continue;
      ++n;
      sum += px[1];
    }
  if (mean_green) *mean_green = n ? sum / n : 0.0;
  return n;
}

// The compositor: an opened mouth shows the exemplar, not the model's teeth and cavity, and
// darker where the output opens less than the still did.
TEST(MouthInteriorTest, TheCompositorFillsTheOpeningWithTheActorsOwnMouth) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const gpu::FaceParameters target = test_face(0.45f);
  const FaceCompositor fc(*test_model(), albedo_map_options());  // the interior wherever the rendered mouth opens
  const cv::Mat frame = render_target(target, cam);
  AlbedoMap albedo;
  fc.ObserveAlbedo(frame, cam, target, &albedo);

  // The still: the actor's frame with the mouth wide open, painted green.
  gpu::FaceParameters wide = target;
  wide.delta[kJawOpenIndex] = 0.8f;
  const MouthExemplar e = green_still(fc, cam, wide);
  ASSERT_FALSE(e.empty());

  auto green_share = [&](const CompositeResult& c) {
    int green = 0, n = 0;
    for (int j = 0; j < cam.height; ++j)
      for (int i = 0; i < cam.width; ++i) {
        if (!c.mouth_mask.at<uchar>(j, i)) continue;
        ++n;
        if (is_green(c.rendered_bgr.at<cv::Vec3b>(j, i))) ++green;
      }
    return n ? static_cast<double>(green) / n : 0.0;
  };
  const CompositeResult with = fc.Compose(frame, cam, target, wide, &albedo, nullptr, &e);
  const CompositeResult without = fc.Compose(frame, cam, target, wide, &albedo);
  ASSERT_TRUE(with.mouth_drawn && without.mouth_drawn);
  EXPECT_TRUE(with.mouth_from_exemplar);
  EXPECT_FALSE(without.mouth_from_exemplar);
  RecordProperty("green_share_with", std::to_string(green_share(with)));
  EXPECT_GT(green_share(with), 0.8) << "the opening shows the still's interior";
  EXPECT_EQ(green_share(without), 0.0) << "the model's teeth and cavity";
  // The same opening: the still at full brightness (its green within a few levels).
  const cv::Scalar mean_with = cv::mean(with.rendered_bgr, with.mouth_mask);
  EXPECT_NEAR(mean_with[1], 200.0, 25.0);
  // Half as open: less light enters, the interior is darker.
  gpu::FaceParameters half = target;
  half.delta[kJawOpenIndex] = 0.4f;
  const CompositeResult narrower = fc.Compose(frame, cam, target, half, &albedo, nullptr, &e);
  ASSERT_TRUE(narrower.mouth_from_exemplar);
  const cv::Scalar mean_half = cv::mean(narrower.rendered_bgr, narrower.mouth_mask);
  EXPECT_LT(mean_half[1], mean_with[1] - 15.0);
  EXPECT_GT(green_share(narrower), 0.8);
  // Just outside the opening, the model's mouth geometry the rasteriser draws up to the lips'
  // silhouette takes the still too: on real video (d6 on the webcam clip) the model's tongue,
  // poking past the inner-lip polygon over the lower lip, the lips' inner faces and the teeth
  // there were a dark, stair-stepped wedge at the corners and a grey-green sliver. Here the
  // output sticks the tongue out over its lower lip: within 4 px outside the polygon, the still's
  // green (sampled just past its opening), not the model's tongue.
  gpu::FaceParameters tongue = wide;
  tongue.delta[kTongueOutIndex] = 0.7f;
  const CompositeResult tongue_with = fc.Compose(frame, cam, target, tongue, &albedo, nullptr, &e);
  cv::Mat inside = cv::Mat::zeros(cam.height, cam.width, CV_8UC1), ring;
  const std::vector<cv::Point> tp = pixel_polygon(fc.MouthOpening(cam, tongue));
  cv::fillPoly(inside, std::vector<std::vector<cv::Point>>{tp}, cv::Scalar(255));
  cv::dilate(inside, ring, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(9, 9)));
  int green_outside = 0;
  for (int j = 0; j < cam.height; ++j)
    for (int i = 0; i < cam.width; ++i) {
      if (!ring.at<uchar>(j, i) || inside.at<uchar>(j, i)) continue;
      if (is_green(tongue_with.rendered_bgr.at<cv::Vec3b>(j, i))) ++green_outside;
    }
  RecordProperty("green_outside_the_polygon", green_outside);
  EXPECT_GT(green_outside, 16) << "25 measured; 8 when only the polygon took the still";
  // A still with another vertex count (a model without the eight inner-lip points) is not used.
  MouthExemplar odd = e;
  odd.opening.pop_back();
  EXPECT_FALSE(fc.Compose(frame, cam, target, wide, &albedo, nullptr, &odd).mouth_from_exemplar);
}

// Past the polygon the still goes only where the frame texture does not show the surface itself:
// at a barely opened, pursed mouth the model's inner lip faces reach past the corners, where the
// target's own lips are what the frame shows. On the webcam clip (d14, output frame 36; an opening
// of 82 px) the still's dark opening drew a grey hook down a corner and a dot under it, 4-11 px
// from the polygon, over lips the frame showed (trusted at 0.6-1). Here a target of a far-from-mean
// identity (its first ten components at the values below, in standard deviations) with its lips
// barely parted, the output parted more with the lips pushed out (mouthFunnel), the still green:
// beyond 2 px outside the output's opening 7 green pixels before, none now; inside it the still.
TEST(MouthInteriorTest, PastTheOpeningTheStillLeavesTheLipsTheFrameShows) {
  FR_REQUIRE_MODEL();
  const FaceModel& model = *test_model();
  const gpu::PinholeCamera cam = test_camera(640, 480);
  gpu::FaceParameters target = test_face(0.45f);
  const float identity[10] = {-2.19f, -1.26f, -0.24f, -0.85f, -1.72f, 0.41f, 4.71f, 1.29f, 1.86f, -4.96f};
  target.alpha = Eigen::VectorXf::Zero(model.num_identity());
  for (int k = 0; k < 10; ++k) target.alpha[k] = identity[k] * model.identity_sigma[k];
  target.delta[kJawOpenIndex] = 0.05f;
  const FaceCompositor fc(model, ReenactmentOptions{});  // the frame texture
  const cv::Mat frame = render_target(target, cam);
  AlbedoMap albedo;
  fc.ObserveAlbedo(frame, cam, target, &albedo);
  gpu::FaceParameters wide = test_face(0.45f);
  wide.delta[kJawOpenIndex] = 0.8f;
  const MouthExemplar e = green_still(fc, cam, wide);
  ASSERT_FALSE(e.empty());
  gpu::FaceParameters out = target;
  out.delta[kJawOpenIndex] = 0.25f;
  out.delta[arkit_blendshape_index("mouthFunnel")] = 0.7f;
  const CompositeResult c = fc.Compose(frame, cam, target, out, &albedo, nullptr, &e);
  ASSERT_TRUE(c.mouth_from_exemplar);
  cv::Mat inside = cv::Mat::zeros(cam.height, cam.width, CV_8UC1), near;
  const std::vector<cv::Point> poly = pixel_polygon(fc.MouthOpening(cam, out));
  cv::fillPoly(inside, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(255));
  cv::dilate(inside, near, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(5, 5)));
  int green_inside = 0, green_beyond = 0;
  for (int j = 0; j < cam.height; ++j)
    for (int i = 0; i < cam.width; ++i) {
      if (!is_green(c.rendered_bgr.at<cv::Vec3b>(j, i))) continue;
      if (inside.at<uchar>(j, i)) ++green_inside;
      if (!near.at<uchar>(j, i)) ++green_beyond;
    }
  RecordProperty("green_inside", green_inside);
  RecordProperty("green_beyond_2px", green_beyond);
  EXPECT_GT(green_inside, 200) << "the opening shows the still";
  EXPECT_EQ(green_beyond, 0) << "the lips the frame shows past the opening keep the frame's colour";
}

// A target frame rendered with known P (the pipeline's ground-truth target): the test face with
// its mouth opened to `jaw`, frame `index` at 30 fps.
capture::RgbdFrame ground_truth_frame(const gpu::PinholeCamera& cam, float jaw, int index) {
  gpu::FaceParameters p = test_face(0.45f);
  p.delta[kJawOpenIndex] = jaw;
  capture::RgbdFrame f;
  f.index = index;
  f.timestamp_s = index / 30.0;
  f.camera = cam;
  f.color = render_target(p, cam);
  f.ground_truth.params = p;
  return f;
}

// The pipeline keeps a still of the target's own open mouth (ground-truth target: frames rendered
// with known P) and says where the interior comes from.
TEST(MouthInteriorTest, ThePipelineTakesTheTargetsWidestFrontalOpening) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  ReenactmentOptions o;
  o.use_ground_truth_target = true;
  auto frame = [&](float jaw, int index) { return ground_truth_frame(cam, jaw, index); };
  SourceExpression open;
  open.weights[kJawOpenIndex] = 0.9f;
  {
    ReenactmentPipeline pipeline(*test_model(), o);
    pipeline.Process(frame(0.0f, 0), &open);
    EXPECT_TRUE(pipeline.mouth_exemplar().empty()) << "a closed mouth is no interior";
    EXPECT_NE(pipeline.summary().mouth_interior.find("not opened the mouth"), std::string::npos)
        << pipeline.summary().mouth_interior;
    pipeline.Process(frame(0.5f, 1), &open);
    ASSERT_FALSE(pipeline.mouth_exemplar().empty());
    EXPECT_EQ(pipeline.mouth_exemplar().frame_index, 1);
    pipeline.Process(frame(0.55f, 2), &open);
    EXPECT_EQ(pipeline.mouth_exemplar().frame_index, 1) << "barely wider: the still stays";
    ReenactedFrame r = pipeline.Process(frame(0.9f, 3), &open);
    EXPECT_EQ(pipeline.mouth_exemplar().frame_index, 3) << "clearly wider";
    EXPECT_FALSE(r.mouth_drawn) << "the target's own mouth is as open as the output's: the frame shows it";
    EXPECT_NE(pipeline.summary().mouth_interior.find("frame 3"), std::string::npos) << pipeline.summary().mouth_interior;
    r = pipeline.Process(frame(0.0f, 4), &open);  // the target closes its mouth, the source keeps it open
    EXPECT_TRUE(r.mouth_drawn && r.mouth_from_exemplar);
    pipeline.RequestCalibration();  // a new person: the still was the other's
    pipeline.Process(frame(0.0f, 5), &open);
    EXPECT_TRUE(pipeline.mouth_exemplar().empty());
  }
  {
    o.mouth_exemplar_frame = 2;  // named: that frame only
    ReenactmentPipeline pipeline(*test_model(), o);
    for (int k = 0; k < 4; ++k) pipeline.Process(frame(k == 2 ? 0.3f : 0.9f, k), &open);
    EXPECT_EQ(pipeline.mouth_exemplar().frame_index, 2);
  }
  {
    o.mouth_exemplar_frame = -1;
    o.mouth_exemplar = false;
    ReenactmentPipeline pipeline(*test_model(), o);
    pipeline.Process(frame(0.9f, 0), &open);
    EXPECT_TRUE(pipeline.mouth_exemplar().empty());
    EXPECT_NE(pipeline.summary().mouth_interior.find("off"), std::string::npos);
  }
  o.mouth_exemplar = true;
  o.mouth_exemplar_frame = -2;
  std::string why;
  EXPECT_FALSE(o.IsValid(&why));
}


// --- the source actor's mouth standing in (ReenactmentOptions::source_mouth) ---

// A target that never opens its mouth, a source whose frame is here: the output's opening shows
// the source's own interior (painted green), carried from the source's light into the target's
// by the skin around both mouths; off, the model's teeth; once the target opens its own mouth,
// its own still.
TEST(MouthInteriorTest, TheSourceActorsMouthStandsInUntilTheTargetOpensItsOwn) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const FaceCompositor fc(*test_model(), ReenactmentOptions{});
  auto target_frame = [&](float jaw, int index) { return ground_truth_frame(cam, jaw, index); };
  // The source's frame: its mouth open, the opening painted green, the whole frame in a light
  // 0.6 times as bright (linear) as the target's.
  gpu::FaceParameters wide = test_face(0.45f);
  wide.delta[kJawOpenIndex] = 0.8f;
  const std::vector<Eigen::Vector2f> opening = fc.MouthOpening(cam, wide);
  ASSERT_EQ(opening.size(), 8u);
  cv::Mat source_bgr = render_target(wide, cam);
  const std::vector<cv::Point> poly = pixel_polygon(opening);
  cv::fillPoly(source_bgr, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(40, 200, 40));
  const auto& lut = srgb_decode_table();
  source_bgr.forEach<cv::Vec3b>([&](cv::Vec3b& px, const int*) {
    for (int k = 0; k < 3; ++k) px[k] = static_cast<uchar>(std::lround(255.f * srgb_encode(0.6f * lut[px[k]])));
  });
  SourceExpression open;
  open.weights[kJawOpenIndex] = 0.8f;
  open.view = std::make_shared<SourceView>(SourceView{source_bgr, cam, wide, 7});

  ReenactmentOptions o;
  o.use_ground_truth_target = true;
  o.detail.mode = DetailMode::kOff;
  {
    ReenactmentPipeline pipeline(*test_model(), o);
    const ReenactedFrame r = pipeline.Process(target_frame(0.f, 0), &open);
    ASSERT_TRUE(r.reenacted && r.mouth_drawn);
    EXPECT_TRUE(r.mouth_from_source && r.mouth_from_exemplar);
    double mean_green = 0;
    const int g = count_green(r.rendered, &mean_green);
    RecordProperty("green_pixels", g);
    RecordProperty("mean_green", std::to_string(mean_green));
    EXPECT_GT(g, 100) << "the source's interior fills the opening";
    // The source's darker light taken out: its green (200 painted, 160 as the source's camera
    // saw it) comes back near 200 in the target's light.
    EXPECT_NEAR(mean_green, 200.0, 20.0);
    EXPECT_NE(pipeline.summary().mouth_interior.find("source actor's own mouth stood in on 1 frame"), std::string::npos)
        << pipeline.summary().mouth_interior;
    // The target opens its own mouth wide: its still takes over, and it is no longer green.
    pipeline.Process(target_frame(0.9f, 1), &open);
    ASSERT_FALSE(pipeline.mouth_exemplar().empty());
    const ReenactedFrame after = pipeline.Process(target_frame(0.f, 2), &open);
    EXPECT_TRUE(after.mouth_from_exemplar);
    EXPECT_FALSE(after.mouth_from_source);
    EXPECT_EQ(count_green(after.rendered), 0);
  }
  {
    o.source_mouth = false;
    ReenactmentPipeline pipeline(*test_model(), o);
    const ReenactedFrame r = pipeline.Process(target_frame(0.f, 0), &open);
    ASSERT_TRUE(r.mouth_drawn);
    EXPECT_FALSE(r.mouth_from_source || r.mouth_from_exemplar);
    EXPECT_EQ(count_green(r.rendered), 0) << "off: the model's teeth";
  }
  {
    // A source whose mouth is closed in its frame (the output opens only by the weights): nothing
    // to take from it.
    o.source_mouth = true;
    SourceExpression shut = open;
    gpu::FaceParameters closed = wide;
    closed.delta[kJawOpenIndex] = 0.f;
    shut.view = std::make_shared<SourceView>(SourceView{render_target(closed, cam), cam, closed, 8});
    ReenactmentPipeline pipeline(*test_model(), o);
    const ReenactedFrame r = pipeline.Process(target_frame(0.f, 0), &shut);
    EXPECT_TRUE(r.mouth_drawn);
    EXPECT_FALSE(r.mouth_from_source);
  }
  // The front-ends attach the source's frame whenever the detail or the mouth uses it: with the
  // detail off (as here) the mouth still does.
  EXPECT_TRUE(o.UsesSourceView());
  o.source_mouth = false;
  EXPECT_FALSE(o.UsesSourceView());
  o.detail.mode = DetailMode::kTransient;
  EXPECT_TRUE(o.UsesSourceView());
  // The front-ends' one mouth setting (reenact --mouth, webcam --mouth, the OBS source's "mouth").
  ReenactmentOptions m;
  ASSERT_TRUE(m.SetMouth("model"));
  EXPECT_FALSE(m.mouth_exemplar);
  ASSERT_TRUE(m.SetMouth("target"));
  EXPECT_TRUE(m.mouth_exemplar);
  EXPECT_FALSE(m.source_mouth);
  ASSERT_TRUE(m.SetMouth("auto"));
  EXPECT_TRUE(m.mouth_exemplar && m.source_mouth);
  EXPECT_FALSE(m.SetMouth("wide"));
  EXPECT_TRUE(m.mouth_exemplar && m.source_mouth);
}

// A source filmed from below (liveportrait_d10 is pitched 17-28 degrees: a phone held low) still
// lends its mouth of that frame: refused beyond the target's still's 20 degrees, the output's
// opening was the model's flat dark cavity on 58 of 86 frames (d10 onto the webcam clip). A
// source turned 50 degrees away lends nothing.
TEST(MouthInteriorTest, ASourceFilmedFromBelowStillLendsItsMouth) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const FaceCompositor fc(*test_model(), ReenactmentOptions{});
  auto source_view = [&](float pitch_deg, float yaw_deg) {
    gpu::FaceParameters p = test_face(0.45f);
    p.delta[kJawOpenIndex] = 0.8f;
    p.euler.x() += pitch_deg * static_cast<float>(M_PI) / 180.f;
    p.euler.y() += yaw_deg * static_cast<float>(M_PI) / 180.f;
    cv::Mat bgr = render_target(p, cam);
    cv::fillPoly(bgr, std::vector<std::vector<cv::Point>>{pixel_polygon(fc.MouthOpening(cam, p))}, cv::Scalar(40, 200, 40));
    SourceExpression e;
    e.weights[kJawOpenIndex] = 0.8f;
    e.view = std::make_shared<SourceView>(SourceView{bgr, cam, p, 3});
    return std::pair{e, gpu::head_turn_from_camera_deg(p)};
  };
  ReenactmentOptions o;
  o.use_ground_truth_target = true;
  o.detail.mode = DetailMode::kOff;
  for (const auto& [pitch, yaw, lends] : {std::tuple{0.f, 0.f, true}, std::tuple{28.f, 0.f, true}, std::tuple{0.f, 50.f, false}}) {
    const auto [expression, turn] = source_view(pitch, yaw);
    ReenactmentPipeline pipeline(*test_model(), o);
    const ReenactedFrame r = pipeline.Process(ground_truth_frame(cam, 0.f, 0), &expression);
    ASSERT_TRUE(r.reenacted && r.mouth_drawn);
    const int green = count_green(r.rendered);
    RecordProperty("green_pixels_pitch_" + std::to_string(static_cast<int>(pitch)) + "_yaw_" + std::to_string(static_cast<int>(yaw)), green);
    EXPECT_EQ(r.mouth_from_source, lends) << "pitch " << pitch << ", yaw " << yaw << " (" << turn << " degrees from the camera)";
    if (lends) EXPECT_GT(green, 100) << "pitch " << pitch << ": the source's interior fills the opening";
    else EXPECT_EQ(green, 0);
  }
}

// --- the teeth proxy's texture (teeth_texture.h) ---

// A drawn smile: skin, red lips, and between them white teeth (rows 50-69, columns 60-139) with
// dark gaps at columns 80, 100 and 120 and a light grey top (rows 50-51). The inner-lip points sit
// as dlib puts them on a small smile: the upper ones 3 px inside the teeth, the corners out on the
// lips.
cv::Mat drawn_smile() {
  cv::Mat photo(120, 200, CV_8UC3, cv::Scalar(150, 170, 205));  // skin (BGR)
  cv::rectangle(photo, cv::Rect(45, 38, 110, 12), cv::Scalar(80, 70, 190), cv::FILLED);  // upper lip
  cv::rectangle(photo, cv::Rect(45, 70, 110, 12), cv::Scalar(80, 70, 190), cv::FILLED);  // lower lip
  cv::rectangle(photo, cv::Rect(45, 50, 15, 20), cv::Scalar(80, 70, 190), cv::FILLED);   // lips at the corners
  cv::rectangle(photo, cv::Rect(140, 50, 15, 20), cv::Scalar(80, 70, 190), cv::FILLED);
  cv::rectangle(photo, cv::Rect(60, 50, 80, 20), cv::Scalar(240, 240, 240), cv::FILLED);  // teeth
  cv::rectangle(photo, cv::Rect(60, 50, 80, 2), cv::Scalar(185, 185, 185), cv::FILLED);   // their grey top
  for (int x : {80, 100, 120}) cv::rectangle(photo, cv::Rect(x - 1, 50, 2, 20), cv::Scalar(60, 60, 70), cv::FILLED);
  return photo;
}
std::vector<Eigen::Vector2f> drawn_smile_lips() {
  return {{50.f, 60.f}, {76.f, 53.f}, {100.f, 53.f}, {124.f, 53.f}, {150.f, 60.f}, {124.f, 69.f}, {100.f, 69.f}, {76.f, 69.f}};
}

TEST(TeethTextureTest, TakesTheTeethFromLipToLipAndCornerToCorner) {
  const TeethTexture t = BuildTeethTexture(drawn_smile(), drawn_smile_lips(), 160, 40);
  ASSERT_EQ(t.bgr.cols, 160);
  ASSERT_EQ(t.bgr.rows, 40);
  auto luma = [&](int i, int j) {
    const cv::Vec3b p = t.bgr.at<cv::Vec3b>(j, i);
    return (p[0] + p[1] + p[2]) / 3.0;
  };
  // Columns: the teeth's span (60-139), not the lips at the corners: the gaps at u 0.25, 0.5,
  // 0.75, each tooth's middle bright.
  for (double u : {0.25, 0.5, 0.75}) {
    double darkest = 255;
    for (int i = static_cast<int>(u * 160) - 4; i <= static_cast<int>(u * 160) + 4; ++i) darkest = std::min(darkest, luma(i, 30));
    EXPECT_LT(darkest, 140.0) << "a gap near u " << u;
  }
  for (double u : {0.125, 0.375, 0.625, 0.875}) EXPECT_GT(luma(static_cast<int>(u * 160), 30), 225.0) << "a tooth at u " << u;
  // Rows: from the teeth's own top (their grey band, above the points' line) to their edge; no lip.
  EXPECT_LT(luma(56, 0), 215.0) << "the grey top of the teeth is the first row";
  EXPECT_GT(luma(56, 0), 160.0);
  for (int j = 0; j < 40; ++j) {
    const cv::Vec3b p = t.bgr.at<cv::Vec3b>(j, 56);
    EXPECT_LT(std::abs(p[2] - p[1]), 40) << "row " << j << " is red: a lip, not a tooth";
  }
  // The reference is the teeth's white; a gap is dark against it, a tooth about 1.
  EXPECT_NEAR(TeethPattern(t, 0.375f, 0.6f).mean(), 1.0f, 0.08f);
  EXPECT_LT(TeethPattern(t, 0.5f, 0.6f).mean(), TeethPattern(t, 0.375f, 0.6f).mean() - 0.3f);
}

TEST(TeethTextureTest, RefusesShutLipsAndBadInput) {
  const cv::Mat photo = drawn_smile();
  std::vector<Eigen::Vector2f> shut = drawn_smile_lips();
  for (int k : {5, 6, 7}) shut[static_cast<size_t>(k)].y() = 53.5f;  // the lower lip on the upper
  EXPECT_THROW(BuildTeethTexture(photo, shut), Error);
  std::vector<Eigen::Vector2f> seven = drawn_smile_lips();
  seven.pop_back();
  EXPECT_THROW(BuildTeethTexture(photo, seven), Error);
  std::vector<Eigen::Vector2f> nan = drawn_smile_lips();
  nan[2].x() = std::nanf("");
  EXPECT_THROW(BuildTeethTexture(photo, nan), Error);
  std::vector<Eigen::Vector2f> outside = drawn_smile_lips();
  outside[4].x() = 250.f;
  EXPECT_THROW(BuildTeethTexture(photo, outside), Error);
  EXPECT_THROW(BuildTeethTexture(cv::Mat(), drawn_smile_lips()), Error);

  const std::filesystem::path dir = std::filesystem::path(::testing::TempDir()) / "teeth_texture_test";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  EXPECT_THROW(LoadTeethTexture((dir / "missing.png").string()), Error);
  std::ofstream((dir / "text.png").string()) << "not a PNG";
  EXPECT_THROW(LoadTeethTexture((dir / "text.png").string()), Error);
  cv::imwrite((dir / "tiny.png").string(), cv::Mat(2, 8, CV_8UC3, cv::Scalar(255, 255, 255)));
  EXPECT_THROW(LoadTeethTexture((dir / "tiny.png").string()), Error);
  // Beside a model: missing is no error (the model's plain teeth), and says what makes it.
  std::string why;
  EXPECT_EQ(LoadDefaultTeethTexture((dir / "face-model.frm").string(), &why), nullptr);
  EXPECT_NE(why.find("model teeth"), std::string::npos) << why;
  EXPECT_EQ(DefaultTeethTexturePath((dir / "face-model.frm").string()), (dir / "face-teeth.png").string());
  const TeethTexture built = BuildTeethTexture(photo, drawn_smile_lips());
  SaveTeethTexture(built, DefaultTeethTexturePath((dir / "face-model.frm").string()));
  const auto loaded = LoadDefaultTeethTexture((dir / "face-model.frm").string(), &why);
  ASSERT_NE(loaded, nullptr);
  EXPECT_EQ(loaded->bgr.size(), built.bgr.size());
  EXPECT_LT((loaded->reference - built.reference).norm(), 1e-4f);
}

TEST(TeethTextureTest, CoordinatesRunAcrossTheArchAndFromGumToEdge) {
  FR_REQUIRE_MODEL();
  const FaceModel& m = *test_model();
  const std::vector<Eigen::Vector2f> uv = TeethTextureCoordinates(m);
  ASSERT_EQ(uv.size(), static_cast<size_t>(m.num_vertices()));
  for (FacePart part : {FacePart::UpperTeeth, FacePart::LowerTeeth}) {
    float v_min = 2.f, v_max = -1.f, mid_u = 0.f;
    int teeth = 0, midline = 0;
    for (int v = 0; v < m.num_vertices(); ++v) {
      if (m.vertex_part[static_cast<size_t>(v)] != part) continue;
      ASSERT_TRUE(uv[static_cast<size_t>(v)].allFinite());
      ++teeth;
      v_min = std::min(v_min, uv[static_cast<size_t>(v)].y());
      v_max = std::max(v_max, uv[static_cast<size_t>(v)].y());
      if (std::abs(m.mean_shape[3 * v]) < 1e-3f) {
        mid_u += uv[static_cast<size_t>(v)].x();
        ++midline;
      }
    }
    ASSERT_GT(teeth, 0);
    EXPECT_NEAR(v_min, 0.f, 1e-5f);
    EXPECT_NEAR(v_max, 1.f, 1e-5f);
    if (midline > 0) EXPECT_NEAR(mid_u / midline, 0.5f, 0.05f) << "the middle of the arch is the middle of the texture";
  }
  for (int v = 0; v < m.num_vertices(); ++v)
    if (m.vertex_part[static_cast<size_t>(v)] == FacePart::Face) EXPECT_FALSE(uv[static_cast<size_t>(v)].allFinite());
}

// The compositor lays the texture over the model's teeth: a white texture changes nothing (the
// pattern is relative to its own white), a striped one darkens the teeth in stripes and leaves
// the rest of the opening as it was.
TEST(TeethTextureTest, TheCompositorLaysItOverTheModelsTeeth) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const gpu::FaceParameters target = test_face(0.4f);
  gpu::FaceParameters wide = target;
  wide.delta[kJawOpenIndex] = 0.8f;
  const cv::Mat frame = render_target(target, cam);
  auto compose = [&](std::shared_ptr<const TeethTexture> texture) {
    ReenactmentOptions o;
    o.appearance = Appearance::kAlbedoMap;
    o.teeth_texture = std::move(texture);
    const FaceCompositor fc(*test_model(), o);
    AlbedoMap albedo;
    fc.ObserveAlbedo(frame, cam, target, &albedo);
    return fc.Compose(frame, cam, target, wide, &albedo);
  };
  auto make = [](bool striped) {
    auto t = std::make_shared<TeethTexture>();
    t->bgr = cv::Mat(16, 64, CV_8UC3, cv::Scalar(255, 255, 255));
    if (striped)
      for (int i = 0; i < 64; i += 8) cv::rectangle(t->bgr, cv::Rect(i, 0, 4, 16), cv::Scalar(0, 0, 0), cv::FILLED);
    t->source = striped ? "stripes" : "white";
    return std::shared_ptr<const TeethTexture>(t);
  };
  const CompositeResult plain = compose(nullptr), white = compose(make(false)), striped = compose(make(true));
  ASSERT_TRUE(plain.mouth_drawn);
  int darker = 0, brighter = 0, changed_white = 0;
  for (int j = 0; j < cam.height; ++j)
    for (int i = 0; i < cam.width; ++i) {
      if (!plain.mouth_mask.at<uchar>(j, i)) continue;
      const cv::Vec3b a = plain.rendered_bgr.at<cv::Vec3b>(j, i), b = striped.rendered_bgr.at<cv::Vec3b>(j, i),
                      c = white.rendered_bgr.at<cv::Vec3b>(j, i);
      const int d = (b[0] + b[1] + b[2]) - (a[0] + a[1] + a[2]);
      if (d < -60) ++darker;
      if (d > 6) ++brighter;
      if (c != a) ++changed_white;
    }
  RecordProperty("darker", darker);
  EXPECT_GT(darker, 20) << "the stripes' dark columns on the teeth";
  EXPECT_EQ(brighter, 0) << "a pattern of white and black only darkens";
  EXPECT_EQ(changed_white, 0) << "a white texture is the model's own teeth";
}
}  // namespace
}  // namespace face_reenact::reenact
