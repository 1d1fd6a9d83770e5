// Expression transfer (Eq. 15 in blendshape space) and the SourceExpression helpers.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/model_file.h"
#include <opencv2/core.hpp>

#include "face_reenact/reenact/closed_loop.h"
#include "face_reenact/reenact/transfer.h"
#include "face_reenact/stream/stream_state.h"

namespace face_reenact::reenact {
namespace {

Eigen::VectorXf constant(float v) { return Eigen::VectorXf::Constant(kNumExpressionWeights, v); }

TEST(ReenactTransferTest, IndicesNameTheArkitShapes) {
  EXPECT_EQ(arkit_blendshape_index("jawOpen"), kJawOpenIndex);
  EXPECT_EQ(arkit_blendshape_index("tongueOut"), kTongueOutIndex);
}

TEST(ReenactTransferTest, AddsTheSourceDeltaToTheTargetNeutral) {
  SourceExpression s;
  s.weights[kJawOpenIndex] = 0.7f;
  s.neutral[kJawOpenIndex] = 0.1f;  // the source rests with the mouth slightly open
  s.weights[0] = 0.2f;
  s.neutral[0] = 0.2f;              // blinks exactly as much as at rest: no change
  Eigen::VectorXf target_neutral = constant(0.0f);
  target_neutral[0] = 0.05f;
  target_neutral[kJawOpenIndex] = 0.05f;
  const Eigen::VectorXf own = constant(0.3f);  // ignored at blend weight 1
  const Eigen::VectorXf out = TransferExpression(target_neutral, own, s);
  ASSERT_EQ(out.size(), kNumExpressionWeights);
  EXPECT_NEAR(out[kJawOpenIndex], 0.05f + 0.6f, 1e-6f);
  EXPECT_NEAR(out[0], 0.05f, 1e-6f);
  for (int i = 1; i < kNumExpressionWeights; ++i)
    if (i != kJawOpenIndex) EXPECT_NEAR(out[i], 0.0f, 1e-6f) << i;
}

TEST(ReenactTransferTest, ClampsToTheBlendshapeRange) {
  SourceExpression s;
  s.weights[3] = 1.0f;
  s.neutral[3] = 0.0f;
  s.weights[4] = 0.0f;
  s.neutral[4] = 0.6f;
  const Eigen::VectorXf out = TransferExpression(constant(0.5f), constant(0.5f), s);
  EXPECT_FLOAT_EQ(out[3], 1.0f);
  EXPECT_FLOAT_EQ(out[4], 0.0f);
  EXPECT_GE(out.minCoeff(), 0.0f);
  EXPECT_LE(out.maxCoeff(), 1.0f);
}

TEST(ReenactTransferTest, BlendWeightCrossFadesToTheTargetsOwnExpression) {
  SourceExpression s;
  s.weights[kJawOpenIndex] = 0.8f;
  Eigen::VectorXf own = constant(0.0f);
  own[kJawOpenIndex] = 0.2f;
  s.blend_weight = 0.0f;
  EXPECT_FLOAT_EQ(TransferExpression(constant(0.f), own, s)[kJawOpenIndex], 0.2f);
  s.blend_weight = 0.25f;
  EXPECT_NEAR(TransferExpression(constant(0.f), own, s)[kJawOpenIndex], 0.25f * 0.8f + 0.75f * 0.2f, 1e-6f);
}

TEST(ReenactTransferTest, NeutralSubtractedWeightsAreUsedAsTheDelta) {
  SourceExpression s;
  s.neutral_subtracted = true;
  s.weights[5] = -0.2f;
  s.neutral[5] = 0.9f;  // ignored
  Eigen::VectorXf target_neutral = constant(0.f);
  target_neutral[5] = 0.5f;
  EXPECT_NEAR(TransferExpression(target_neutral, constant(0.f), s)[5], 0.3f, 1e-6f);
}

TEST(ReenactTransferTest, ShortVectorsCountAsZeros) {
  SourceExpression s;
  s.weights[40] = 0.4f;
  const Eigen::VectorXf out = TransferExpression(Eigen::VectorXf(), Eigen::VectorXf(), s);
  EXPECT_FLOAT_EQ(out[40], 0.4f);
}

TEST(ReenactTransferTest, RejectsInvalidSources) {
  SourceExpression s;
  s.weights[2] = std::numeric_limits<float>::quiet_NaN();
  std::string why;
  EXPECT_FALSE(s.IsValid(&why));
  EXPECT_NE(why.find("weight 2"), std::string::npos) << why;
  EXPECT_THROW(TransferExpression(constant(0.f), constant(0.f), s), Error);
  SourceExpression b;
  b.blend_weight = 1.5f;
  EXPECT_FALSE(b.IsValid(&why));
  SourceExpression big;
  big.weights[0] = 7.0f;
  EXPECT_FALSE(big.IsValid(&why));
  SourceExpression bad_neutral;
  bad_neutral.neutral[1] = std::numeric_limits<float>::infinity();
  EXPECT_FALSE(bad_neutral.IsValid(&why));
  bad_neutral.neutral_subtracted = true;  // the neutral is then unused
  EXPECT_TRUE(bad_neutral.IsValid(&why)) << why;
}

TEST(ReenactTransferTest, TransferParametersKeepsEverythingButTheExpression) {
  gpu::FaceParameters target = gpu::frontal_pose(0.7f);
  target.alpha = Eigen::VectorXf::Constant(4, 0.01f);
  target.beta = Eigen::VectorXf::Constant(3, 0.2f);
  target.delta = constant(0.1f);
  target.gamma[4] = 0.3f;
  target.euler.y() = 0.2f;
  gpu::FaceParameters neutral = target;
  neutral.delta = constant(0.0f);
  SourceExpression s;
  s.weights[kJawOpenIndex] = 0.9f;
  const gpu::FaceParameters out = TransferParameters(target, neutral, s);
  EXPECT_EQ(out.alpha, target.alpha);
  EXPECT_EQ(out.beta, target.beta);
  EXPECT_EQ(out.gamma, target.gamma);
  EXPECT_EQ(out.euler, target.euler);
  EXPECT_EQ(out.translation, target.translation);
  EXPECT_FLOAT_EQ(out.delta[kJawOpenIndex], 0.9f);
  EXPECT_FLOAT_EQ(out.delta[0], 0.0f);
}

TEST(ReenactTransferTest, SourceFromParametersAndRemote) {
  gpu::FaceParameters tracked, neutral;
  tracked.delta = constant(0.4f);
  neutral.delta = Eigen::VectorXf::Constant(10, 0.1f);  // shorter: the rest are 0
  const SourceExpression s = SourceFromParameters(tracked, neutral);
  EXPECT_FALSE(s.neutral_subtracted);
  EXPECT_NEAR(s.relative()[3], 0.3f, 1e-6f);
  EXPECT_NEAR(s.relative()[30], 0.4f, 1e-6f);

  tracker::TrackedFrame lost;
  lost.status = tracker::TrackingStatus::kLost;
  lost.has_parameters = true;
  lost.params = tracked;
  EXPECT_FLOAT_EQ(SourceFromTrackedFrame(lost, neutral).blend_weight, 0.0f);
  lost.status = tracker::TrackingStatus::kTracking;
  EXPECT_FLOAT_EQ(SourceFromTrackedFrame(lost, neutral).blend_weight, 1.0f);

  stream::RemoteExpression remote;
  EXPECT_FLOAT_EQ(SourceFromRemote(remote).blend_weight, 0.0f);  // no frame yet
  remote.has_frame = true;
  remote.weight = 0.5f;
  remote.expression[kJawOpenIndex] = 0.6f;
  remote.expression[1] = std::numeric_limits<float>::quiet_NaN();
  const SourceExpression r = SourceFromRemote(remote);
  std::string why;
  EXPECT_TRUE(r.IsValid(&why)) << why;
  EXPECT_TRUE(r.neutral_subtracted);
  EXPECT_FLOAT_EQ(r.blend_weight, 0.5f);
  EXPECT_FLOAT_EQ(r.weights[kJawOpenIndex], 0.6f);
  EXPECT_FLOAT_EQ(r.weights[1], 0.0f);
}

}  // namespace
}  // namespace face_reenact::reenact

// The demo's closed-loop yardstick (closed_loop.h): each figure is the mean over the frames it
// counts, frames without a fit or before calibration are not counted, and an identity compared
// with itself is 0 mm away.
namespace face_reenact::reenact {
namespace {

TEST(ClosedLoopScore, CountsTheFramesItShouldAndAveragesTheErrors) {
  const char* path = std::getenv("FR_MODEL");
  if (!path || !std::filesystem::exists(path)) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const tracker::TrackerModel model = tracker::TrackerModel::FromFaceModel(load_face_model(path));
  gpu::PinholeCamera camera;
  camera.width = 320;
  camera.height = 240;
  camera.fx = camera.fy = 280;
  camera.cx = 159.5f;
  camera.cy = 119.5f;
  ClosedLoopScore score(model, camera);
  ClosedLoopScore::Summary empty = score.summary();
  EXPECT_EQ(empty.loop_frames, 0);
  EXPECT_TRUE(std::isnan(empty.expression_error));

  const Eigen::VectorXf truth = Eigen::VectorXf::Constant(kNumExpressionWeights, 0.2f);
  tracker::TrackedFrame fit;
  fit.status = tracker::TrackingStatus::kTracking;
  fit.has_parameters = true;
  fit.params.delta = truth;
  fit.params.delta[kJawOpenIndex] += 0.52f;  // one weight 0.52 off: 0.01 over the 52
  score.AddSource(fit, /*source_calibrated=*/true, truth);
  score.AddSource(fit, /*source_calibrated=*/false, truth);  // not counted
  tracker::TrackedFrame lost = fit;
  lost.status = tracker::TrackingStatus::kLost;
  score.AddSource(lost, true, truth);  // not counted
  const Eigen::VectorXf alpha = Eigen::VectorXf::Constant(model.num_identity(), 0.01f);
  score.AddLoop(fit, /*loop_calibrated=*/true, alpha, truth, fit.params.delta, alpha);
  score.AddLoop(fit, /*loop_calibrated=*/false, alpha, truth, truth, alpha);  // not counted
  score.AddTargetIdentity(alpha, alpha);
  const ClosedLoopScore::Summary s = score.summary();
  EXPECT_NEAR(s.source_expression_error, 0.01, 1e-6);
  EXPECT_EQ(s.loop_frames, 1);
  EXPECT_NEAR(s.expression_error, 0.01, 1e-6);
  EXPECT_NEAR(s.jaw_open_error, 0.52, 1e-6);
  EXPECT_NEAR(s.expression_error_vs_rendered, 0.0, 1e-9);
  EXPECT_NEAR(s.identity_error_mm, 0.0, 1e-3);
  EXPECT_NEAR(s.target_identity_error_mm, 0.0, 1e-3);
  EXPECT_NEAR(ExpressionError(truth, truth), 0.0, 1e-12);
  // Per blendshape: all of the loop's error on jawOpen, and it leads the worst.
  ASSERT_EQ(s.expression_error_by_blendshape.size(), static_cast<size_t>(kNumExpressionWeights));
  EXPECT_NEAR(s.expression_error_by_blendshape[kJawOpenIndex], 0.52, 1e-6);
  EXPECT_NEAR(s.expression_error_by_blendshape[0], 0.0, 1e-6);
  const auto worst = s.WorstBlendshapes(3);
  ASSERT_EQ(worst.size(), 3u);
  EXPECT_EQ(worst[0].first, "jawOpen");
  EXPECT_NEAR(worst[0].second, 0.52, 1e-6);
  EXPECT_TRUE(empty.expression_error_by_blendshape.empty());
  EXPECT_TRUE(empty.WorstBlendshapes(5).empty());
}

// The rendering's fidelity (closed_loop.h) against figures worked out by hand: 10 levels off
// everywhere is 10 log10(255^2 / 100) = 28.13 dB; two flat regions of luma 100 and 110 have the
// SSIM of their means alone, (2 ab + C1) / (a^2 + b^2 + C1) = 0.99548; what lies outside the mask
// is not measured; identical faces are infinitely close (99 dB in a clip's mean).
TEST(FaceFidelity, MatchesTheFormulasAndMeasuresOnlyTheFace) {
  const cv::Mat reference(60, 80, CV_8UC3, cv::Scalar(100, 100, 100));
  cv::Mat output(60, 80, CV_8UC3, cv::Scalar(110, 110, 110));
  cv::Mat mask = cv::Mat::zeros(60, 80, CV_8UC1);
  mask(cv::Rect(20, 15, 40, 30)).setTo(255);
  output(cv::Rect(0, 0, 10, 10)).setTo(cv::Scalar(0, 0, 255));  // outside the face
  const FaceFidelity off = MeasureFaceFidelity(reference, output, mask);
  EXPECT_EQ(off.pixels, 40 * 30);
  EXPECT_NEAR(off.psnr_db, 28.1308, 1e-3);
  const double c1 = std::pow(0.01 * 255.0, 2);
  EXPECT_NEAR(off.ssim, (2 * 100.0 * 110.0 + c1) / (100.0 * 100.0 + 110.0 * 110.0 + c1), 1e-6);
  const FaceFidelity same = MeasureFaceFidelity(reference, reference, mask);
  EXPECT_TRUE(std::isinf(same.psnr_db));
  EXPECT_NEAR(same.ssim, 1.0, 1e-12);
  // A pattern the output loses (a checkerboard the output renders flat) costs structure.
  cv::Mat textured = reference.clone();
  for (int j = 0; j < textured.rows; ++j)
    for (int i = 0; i < textured.cols; ++i)
      if ((i / 2 + j / 2) % 2) textured.at<cv::Vec3b>(j, i) = cv::Vec3b(140, 140, 140);
  EXPECT_LT(MeasureFaceFidelity(textured, reference, mask).ssim, 0.5);
  const FaceFidelity none = MeasureFaceFidelity(reference, output, cv::Mat::zeros(60, 80, CV_8UC1));
  EXPECT_EQ(none.pixels, 0);
  EXPECT_TRUE(std::isnan(none.psnr_db));
  EXPECT_THROW(MeasureFaceFidelity(reference, output, cv::Mat::zeros(30, 40, CV_8UC1)), Error);
  EXPECT_THROW(MeasureFaceFidelity(reference, cv::Mat(60, 80, CV_8UC1), mask), Error);

  FaceFidelityTally tally;
  EXPECT_TRUE(std::isnan(tally.summary().psnr_db));
  tally.Add(off);
  tally.Add(same);
  tally.Add(none);  // not counted
  const FaceFidelityTally::Summary s = tally.summary();
  EXPECT_EQ(s.frames, 2);
  EXPECT_NEAR(s.psnr_db, (28.1308 + 99.0) / 2, 1e-3);
  EXPECT_NEAR(s.psnr_db_min, 28.1308, 1e-3);
  EXPECT_NEAR(s.ssim, (off.ssim + 1.0) / 2, 1e-9);
}

}  // namespace
}  // namespace face_reenact::reenact
