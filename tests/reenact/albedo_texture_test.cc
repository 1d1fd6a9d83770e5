// The actor's albedo texture (albedo_texture.h): the UV layout, one view's unwrap, the multi-band
// blend of views, the choice of views and the pipeline that builds it, on rendered faces whose
// parameters are known.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <thread>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/reenact/albedo_texture.h"
#include "face_reenact/reenact/face_compositor.h"
#include "face_reenact/reenact/reenactment_pipeline.h"
#include "face_reenact/reenact/transfer.h"
#include "reenact_test_support.h"

namespace face_reenact::reenact {
namespace {

using testing::render_target;
using testing::test_camera;
using testing::test_face;
using testing::albedo_map_options;
using testing::test_model;
using testing::mean_abs_diff;

gpu::FaceParameters turned(float yaw_deg, float distance = 0.5f) {
  gpu::FaceParameters p = test_face(distance);
  p.euler[1] += yaw_deg * static_cast<float>(M_PI / 180.0);
  return p;
}

// A target frame of the face turned by `yaw_deg`, with its ground truth (the pipeline's
// use_ground_truth_target).
capture::RgbdFrame frame_turned(float yaw_deg, int index, const gpu::PinholeCamera& cam) {
  capture::RgbdFrame f;
  f.index = index;
  f.timestamp_s = index / 30.0;
  f.camera = cam;
  f.ground_truth.params = turned(yaw_deg, 0.4f);
  f.color = render_target(*f.ground_truth.params, cam);
  return f;
}

// The per-vertex map and the texture of one frame, as the pipeline makes them.
AlbedoMap learn(const FaceCompositor& fc, const std::shared_ptr<const AlbedoTextureLayout>& layout,
                const std::vector<std::pair<cv::Mat, gpu::FaceParameters>>& views, const gpu::PinholeCamera& cam) {
  AlbedoMap map;
  for (const auto& [frame, p] : views) fc.ObserveAlbedo(frame, cam, p, &map);
  std::vector<FaceCompositor::AlbedoTextureFrame> frames;
  for (const auto& [frame, p] : views) frames.push_back({frame, cv::Mat(), cam, p, -1});
  map.texture = std::make_shared<const AlbedoTexture>(fc.BuildAlbedoTexture(frames, layout, map.albedo, 5));
  return map;
}

TEST(AlbedoTextureTest, EveryTexelLiesWhereItsTrianglesUvsPutIt) {
  FR_REQUIRE_MODEL();
  const FaceModel& model = *test_model();
  const auto layout = AlbedoTextureLayout::ForModel(model, 2048);
  // The face's island of the MakeHuman layout: about a fifth of the square on each side.
  EXPECT_GT(layout->width, 300);
  EXPECT_LT(layout->width, 700);
  EXPECT_GT(layout->height, 300);
  EXPECT_LT(layout->height, 700);
  int textured = 0;
  for (char t : layout->textured) textured += t;
  EXPECT_GT(textured, 3000) << "the face's main island";
  int interior = 0, gutter = 0;
  float worst_interior = 0.f, worst_gutter = 0.f;
  for (int j = 0; j < layout->height; ++j)
    for (int i = 0; i < layout->width; ++i) {
      const size_t texel = static_cast<size_t>(j) * layout->width + i;
      const int32_t t = layout->triangle[texel];
      if (t < 0) continue;
      ASSERT_TRUE(layout->textured[static_cast<size_t>(t)]);
      Eigen::Vector2f uv = Eigen::Vector2f::Zero();
      float bsum = 0.f;
      for (size_t k = 0; k < 3; ++k) {
        const float b = layout->barycentric[3 * texel + k];
        ASSERT_GE(b, 0.f);
        bsum += b;
        const auto& c = model.corner_uvs[3 * static_cast<size_t>(t) + k];
        uv += b * Eigen::Vector2f(c[0], c[1]);
        EXPECT_EQ(layout->vertices[3 * texel + k], model.triangles[static_cast<size_t>(t)][k]);
      }
      EXPECT_NEAR(bsum, 1.f, 1e-4f);
      const float d = (layout->ToTexel(uv) - Eigen::Vector2f(static_cast<float>(i), static_cast<float>(j))).norm();
      // Interior texels reproduce their own centre; gutter texels lie within two texels of the
      // point of the triangle they took.
      if (d < 1e-2f) {
        ++interior;
        worst_interior = std::max(worst_interior, d);
      } else {
        ++gutter;
        worst_gutter = std::max(worst_gutter, d);
      }
    }
  RecordProperty("interior_texels", interior);
  RecordProperty("gutter_texels", gutter);
  EXPECT_GT(interior, 80000);
  EXPECT_GT(gutter, 100);
  EXPECT_LT(gutter, interior / 5);
  EXPECT_LE(worst_gutter, 2.0f + 1e-3f);
  // Half the size: the same island at half the texels.
  const auto half = AlbedoTextureLayout::ForModel(model, 1024);
  EXPECT_NEAR(half->width, layout->width / 2, 8);  // each side's margin is a few texels at any size
  EXPECT_THROW(AlbedoTextureLayout::ForModel(model, 16), Error);
}

// The multi-band blend of two views, each sure of one half: each half is its view's colour, a
// fine pattern only one view shows keeps its full contrast away from the meeting line, and across
// the line the colour changes over many texels (no seam). A view that sees nothing changes nothing.
TEST(AlbedoTextureTest, TwoViewsMeetWithoutASeamAndKeepTheirFinestDetail) {
  FR_REQUIRE_MODEL();
  const FaceModel& model = *test_model();
  const auto layout = AlbedoTextureLayout::ForModel(model, 512);
  const cv::Size size(layout->width, layout->height);
  const cv::Vec3f left_colour(0.6f, 0.4f, 0.3f), right_colour(0.3f, 0.35f, 0.5f);
  AlbedoTextureView a, b, nothing;
  a.albedo = cv::Mat(size, CV_32FC3, cv::Scalar(left_colour));
  b.albedo = cv::Mat(size, CV_32FC3, cv::Scalar(right_colour));
  // View a carries a one-texel checker of +-0.1 (pores, stubble) over its half.
  for (int j = 0; j < size.height; ++j)
    for (int i = 0; i < size.width / 2; ++i) a.albedo.at<cv::Vec3f>(j, i) += cv::Vec3f::all((i + j) % 2 ? 0.1f : -0.1f);
  a.weight = cv::Mat::zeros(size, CV_32FC1);
  b.weight = cv::Mat::zeros(size, CV_32FC1);
  a.weight(cv::Rect(0, 0, size.width / 2, size.height)).setTo(1.0f);
  b.weight(cv::Rect(size.width / 2, 0, size.width - size.width / 2, size.height)).setTo(1.0f);
  nothing.albedo = cv::Mat(size, CV_32FC3, cv::Scalar::all(1.0f));
  nothing.weight = cv::Mat::zeros(size, CV_32FC1);
  const Eigen::VectorXf base = Eigen::VectorXf::Constant(3 * model.num_vertices(), 0.5f);
  const AlbedoTexture t = BlendAlbedoViews(layout, {a, b}, base, 5);
  ASSERT_EQ(t.albedo.size(), size);
  ASSERT_EQ(t.views.size(), 2u);

  const int row = size.height / 2, mid = size.width / 2;
  ASSERT_GE(layout->triangle[static_cast<size_t>(row) * size.width + mid], 0) << "the island's middle row";
  auto at = [&](int i) { return t.albedo.at<cv::Vec3f>(row, i); };
  // Far from the line, each view's colour (the checker averaged over a pair of texels).
  const cv::Vec3f far_left = 0.5f * (at(mid - 40) + at(mid - 41)), far_right = at(mid + 40);
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(far_left[c], left_colour[c], 0.01f) << c;
    EXPECT_NEAR(far_right[c], right_colour[c], 0.01f) << c;
  }
  // The checker keeps its contrast: neighbouring texels 0.2 apart.
  EXPECT_NEAR(std::abs(at(mid - 40)[1] - at(mid - 41)[1]), 0.2f, 0.02f);
  // Across the line, without the checker: no step between neighbouring texels of more than a
  // fifth of the colours' difference (a seam would be all of it at once).
  AlbedoTextureView plain = a;
  plain.albedo = cv::Mat(size, CV_32FC3, cv::Scalar(left_colour));
  const AlbedoTexture smooth = BlendAlbedoViews(layout, {plain, b}, base, 5);
  const float total = std::abs(left_colour[0] - right_colour[0]);
  float worst_step = 0.f;
  for (int i = mid - 20; i < mid + 20; ++i)
    worst_step = std::max(worst_step, std::abs(smooth.albedo.at<cv::Vec3f>(row, i + 1)[0] - smooth.albedo.at<cv::Vec3f>(row, i)[0]));
  RecordProperty("worst_step_across_the_line", std::to_string(worst_step));
  EXPECT_LT(worst_step, 0.2f * total);
  EXPECT_GT(smooth.albedo.at<cv::Vec3f>(row, mid - 20)[0] - smooth.albedo.at<cv::Vec3f>(row, mid + 20)[0], 0.5f * total)
      << "the change happens around the line";

  const AlbedoTexture same = BlendAlbedoViews(layout, {a, b, nothing}, base, 5);
  EXPECT_LT(cv::norm(same.albedo, t.albedo, cv::NORM_INF), 1e-5);

  // Bad input: a view of the wrong size, a base of another model.
  AlbedoTextureView wrong = a;
  wrong.albedo = cv::Mat(10, 10, CV_32FC3, cv::Scalar::all(0.5f));
  EXPECT_THROW(BlendAlbedoViews(layout, {wrong}, base, 5), Error);
  EXPECT_THROW(BlendAlbedoViews(layout, {a}, Eigen::VectorXf::Constant(30, 0.5f), 5), Error);
}

// The point of the texture: a pattern finer than the mesh (a stand-in for pores and stubble)
// comes back in a pass-through with Appearance::kAlbedoMap, where the per-vertex map alone
// smooths it away; and the unwrap divides by the shading the re-rendering multiplies with.
TEST(AlbedoTextureTest, HoldsTheDetailThePerVertexMapCannot) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const gpu::FaceParameters p = test_face(0.5f);
  const FaceCompositor fc(*test_model(), albedo_map_options());
  const cv::Mat detailed = testing::with_fine_pattern(render_target(p, cam));
  const auto layout = AlbedoTextureLayout::ForModel(*test_model(), 2048);
  AlbedoMap with = learn(fc, layout, {{detailed, p}}, cam);
  AlbedoMap without = with;
  without.texture.reset();
  ASSERT_GT(with.texture->views.at(0).seen_texels, 50000);
  const CompositeResult a = fc.Compose(detailed, cam, p, p, &with);
  const CompositeResult b = fc.Compose(detailed, cam, p, p, &without);
  ASSERT_TRUE(a.drawn && b.drawn);
  const double kept = mean_abs_diff(a.bgr, detailed, a.face_mask), lost = mean_abs_diff(b.bgr, detailed, b.face_mask);
  RecordProperty("texture_mean_abs_diff", std::to_string(kept));
  RecordProperty("per_vertex_mean_abs_diff", std::to_string(lost));
  EXPECT_GT(lost, 5.0) << "the per-vertex map cannot hold a per-pixel pattern; the test would not show the difference";
  EXPECT_LT(kept, 0.6 * lost);
}

// Detail is held by the surface: a dark mark painted on the cheek of a frontal frame shows, in
// a render of the face turned 12 degrees and moved 2 cm sideways, where that surface point now
// projects, and is gone from where it was.
TEST(AlbedoTextureTest, AMarkMovesWithTheSurfaceToAnotherPose) {
  FR_REQUIRE_MODEL();
  const FaceModel& model = *test_model();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const gpu::FaceParameters front = test_face(0.45f);
  gpu::FaceParameters side = turned(12.f, 0.45f);
  side.translation.x() += 0.02f;
  ReenactmentOptions o;
  o.appearance = Appearance::kAlbedoMap;
  const FaceCompositor fc(model, o);
  // A cheek vertex: iBUG 31 (the nose's left wing) moved 2 cm outwards in the mean shape.
  int32_t wing = -1;
  for (const auto& l : model.landmarks)
    if (l.ibug_index == 31) wing = l.vertex;
  ASSERT_GE(wing, 0);
  const float outwards = model.mean_shape[3 * wing] > 0.f ? 1.f : -1.f;
  const Eigen::Vector3f want = model.mean_shape.segment<3>(3 * wing) + Eigen::Vector3f(outwards * 0.02f, 0.f, 0.f);
  int32_t cheek = -1;
  float best = 1e9f;
  for (int v = 0; v < model.num_vertices(); ++v) {
    if (model.vertex_part[static_cast<size_t>(v)] != FacePart::Face) continue;
    const float d = (model.mean_shape.segment<3>(3 * v) - want).squaredNorm();
    if (d < best) best = d, cheek = v;
  }
  const gpu::CpuRenderer renderer(gpu::RenderModel::FromFaceModel(model));
  auto project = [&](const gpu::FaceParameters& p) {
    const Eigen::Vector3f x = renderer.evaluate(p).camera_positions.segment<3>(3 * cheek);
    return cv::Point2f(cam.fx * x.x() / x.z() + cam.cx, cam.fy * x.y() / x.z() + cam.cy);
  };
  const cv::Point2f before = project(front), after = project(side);
  ASSERT_GT(cv::norm(after - before), 6.0) << "the turn should move the cheek by several pixels";
  cv::Mat marked = render_target(front, cam);
  cv::circle(marked, cv::Point(cvRound(before.x), cvRound(before.y)), 2, cv::Scalar(30, 30, 30), cv::FILLED);
  const auto layout = AlbedoTextureLayout::ForModel(model, 2048);
  const AlbedoMap map = learn(fc, layout, {{marked, front}}, cam);
  const cv::Mat side_frame = render_target(side, cam);
  const CompositeResult c = fc.Compose(side_frame, cam, side, side, &map);
  ASSERT_TRUE(c.drawn);
  auto darkness = [&](const cv::Mat& img, cv::Point2f at) {
    const cv::Rect r(cvRound(at.x) - 1, cvRound(at.y) - 1, 3, 3);
    const cv::Scalar m = cv::mean(img(r)), ref = cv::mean(side_frame(r));
    return ((ref[0] + ref[1] + ref[2]) - (m[0] + m[1] + m[2])) / 3.0;
  };
  RecordProperty("darkening_where_the_point_went", std::to_string(darkness(c.bgr, after)));
  RecordProperty("darkening_where_it_was", std::to_string(darkness(c.bgr, before)));
  EXPECT_GT(darkness(c.bgr, after), 40.0);
  EXPECT_LT(darkness(c.bgr, before), 15.0);
}

TEST(AlbedoTextureTest, ViewsAreAFrontAndATurnToEachSideAtRest) {
  AlbedoTextureOptions o;
  std::string why;
  ASSERT_TRUE(o.IsValid(&why)) << why;
  AlbedoViewChooser chooser(o);
  EXPECT_EQ(chooser.Consider(turned(5.f)), AlbedoViewChooser::kFront);
  EXPECT_EQ(chooser.Consider(turned(4.f)), AlbedoViewChooser::kNone) << "not clearly better";
  EXPECT_EQ(chooser.Consider(turned(1.f)), AlbedoViewChooser::kFront);
  const float yaw = head_yaw_deg(turned(-15.f));
  EXPECT_NEAR(std::abs(yaw), 15.f, 0.5f);
  const AlbedoViewChooser::Slot one_side = yaw < 0 ? AlbedoViewChooser::kLeft : AlbedoViewChooser::kRight;
  const AlbedoViewChooser::Slot other_side = yaw < 0 ? AlbedoViewChooser::kRight : AlbedoViewChooser::kLeft;
  EXPECT_EQ(chooser.Consider(turned(-15.f)), one_side);
  EXPECT_EQ(chooser.Consider(turned(-21.f)), one_side) << "closer to 20 degrees";
  EXPECT_EQ(chooser.Consider(turned(-40.f)), AlbedoViewChooser::kNone) << "too far";
  gpu::FaceParameters open = turned(20.f);
  open.delta[kJawOpenIndex] = 0.6f;
  EXPECT_EQ(chooser.Consider(open), AlbedoViewChooser::kNone) << "the mouth open";
  EXPECT_EQ(chooser.Consider(turned(20.f)), other_side);
  EXPECT_EQ(chooser.filled_count(), 3);
  gpu::FaceParameters broken = turned(0.f);
  broken.translation.x() = std::nanf("");
  EXPECT_EQ(chooser.Consider(broken), AlbedoViewChooser::kNone);
  chooser.Reset();
  EXPECT_EQ(chooser.filled_count(), 0);
  // A head pitched against the camera (a phone held low: d10 throughout) is the front view while
  // no level one is; a level one replaces it, and it never replaces a level one. Too steep, none.
  auto pitched = [](float pitch_deg) {
    gpu::FaceParameters p = turned(0.f);
    p.euler[0] += pitch_deg * static_cast<float>(M_PI / 180.0);
    return p;
  };
  EXPECT_EQ(chooser.Consider(pitched(40.f)), AlbedoViewChooser::kNone) << "too steep";
  EXPECT_EQ(chooser.Consider(pitched(20.f)), AlbedoViewChooser::kFront);
  EXPECT_EQ(chooser.Consider(turned(3.f)), AlbedoViewChooser::kFront);
  EXPECT_EQ(chooser.Consider(pitched(-20.f)), AlbedoViewChooser::kNone);
  chooser.Reset();

  // The closed-eyes view: a blink facing the camera, the more closed the better; not a blink turned
  // aside, not one eye (a wink), not with the mouth open; it takes no front slot.
  auto blink = [](float yaw_deg, float left, float right) {
    gpu::FaceParameters p = turned(yaw_deg);
    p.delta[arkit_blendshape_index("eyeBlinkLeft")] = left;
    p.delta[arkit_blendshape_index("eyeBlinkRight")] = right;
    return p;
  };
  EXPECT_EQ(chooser.Consider(blink(15.f, 0.9f, 0.9f)), AlbedoViewChooser::kNone) << "turned aside";
  EXPECT_EQ(chooser.Consider(blink(0.f, 0.9f, 0.1f)), AlbedoViewChooser::kNone) << "a wink";
  gpu::FaceParameters talking = blink(0.f, 0.9f, 0.9f);
  talking.delta[kJawOpenIndex] = 0.6f;
  EXPECT_EQ(chooser.Consider(talking), AlbedoViewChooser::kNone) << "the mouth open";
  EXPECT_EQ(chooser.Consider(blink(0.f, 0.5f, 0.6f)), AlbedoViewChooser::kClosedEyes);
  EXPECT_EQ(chooser.Consider(blink(0.f, 0.55f, 0.6f)), AlbedoViewChooser::kNone) << "not clearly more closed";
  EXPECT_EQ(chooser.Consider(blink(0.f, 0.9f, 0.8f)), AlbedoViewChooser::kClosedEyes);
  EXPECT_FALSE(chooser.filled(AlbedoViewChooser::kFront));
  EXPECT_EQ(chooser.filled_count(), 1);
  chooser.Reset();

  o.size = 10;
  EXPECT_FALSE(o.IsValid(&why));
  o = AlbedoTextureOptions{};
  o.side_yaw_deg = std::nanf("");
  EXPECT_FALSE(o.IsValid(&why));
  o = AlbedoTextureOptions{};
  o.max_front_pitch_deg = 0.f;
  EXPECT_FALSE(o.IsValid(&why));
  o = AlbedoTextureOptions{};
  o.min_closed_eyes_blink = 0.2f;  // a resting eye would count as closed
  EXPECT_FALSE(o.IsValid(&why));
  o = AlbedoTextureOptions{};
  o.size = 0;  // off
  EXPECT_TRUE(o.IsValid(&why)) << why;
}

// The pipeline keeps a front view and one per side from the target's frames and builds the
// texture once the per-vertex map has its first observations; size 0 builds none.
TEST(AlbedoTextureTest, ThePipelineBuildsItFromAFrontAndTwoSideViews) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(160, 120);
  auto run = [&](int size) {
    ReenactmentOptions o;
    o.use_ground_truth_target = true;
    o.albedo_texture.size = size;
    ReenactmentPipeline pipeline(*test_model(), o);
    const float yaws[] = {3.f, 0.f, -20.f, -18.f, 20.f, 17.f, 1.f, 0.f, 0.f, 0.f};
    int index = 0;
    for (float yaw : yaws) {
      const ReenactedFrame r = pipeline.Process(frame_turned(yaw, index++, cam), nullptr);
      EXPECT_TRUE(r.reenacted) << r.message;
    }
    return pipeline.summary();
  };
  const PipelineSummary s = run(1024);
  ASSERT_EQ(s.albedo_texture_views.size(), 3u) << s.albedo_texture_note;
  EXPECT_EQ(s.albedo_texture_builds, 1);
  EXPECT_EQ(s.albedo_texture_views[0].frame_index, 1);  // the one facing the camera
  EXPECT_NEAR(std::abs(s.albedo_texture_views[1].yaw_deg), 20.f, 0.5f);
  EXPECT_NEAR(std::abs(s.albedo_texture_views[2].yaw_deg), 20.f, 0.5f);
  EXPECT_LT(s.albedo_texture_views[1].yaw_deg * s.albedo_texture_views[2].yaw_deg, 0.f) << "one to each side";
  for (const auto& v : s.albedo_texture_views) EXPECT_GT(v.seen_texels, 10000);
  const PipelineSummary off = run(0);
  EXPECT_TRUE(off.albedo_texture_views.empty());
  EXPECT_EQ(off.albedo_texture_note, "off");
}

// A resting eye folds its upper lids away (the front and side views show them squeezed, and
// teach the texture nothing there); a blink shows them. The closed-eyes view is taken on those lids
// alone: the texture's summed weight grows only on triangles an eyeBlink moves. The pipeline keeps
// the target's blink facing the camera as that view.
TEST(AlbedoTextureTest, TheClosedEyesViewIsTakenOnTheLidsAlone) {
  FR_REQUIRE_MODEL();
  const FaceModel& model = *test_model();
  const gpu::PinholeCamera cam = test_camera(640, 480);
  const FaceCompositor fc(model, ReenactmentOptions{});
  const auto layout = AlbedoTextureLayout::ForModel(model, 1024);
  const gpu::FaceParameters front = test_face(0.3f);
  gpu::FaceParameters blink = front;
  blink.delta[arkit_blendshape_index("eyeBlinkLeft")] = 0.8f;
  blink.delta[arkit_blendshape_index("eyeBlinkRight")] = 0.8f;
  AlbedoMap map;
  fc.ObserveAlbedo(render_target(front, cam), cam, front, &map);
  const FaceCompositor::AlbedoTextureFrame front_view{render_target(front, cam), cv::Mat(), cam, front, 0, false};
  const FaceCompositor::AlbedoTextureFrame closed_view{render_target(blink, cam), cv::Mat(), cam, blink, 1, true};
  const AlbedoTexture alone = fc.BuildAlbedoTexture({front_view}, layout, map.albedo, 5);
  const AlbedoTexture with = fc.BuildAlbedoTexture({front_view, closed_view}, layout, map.albedo, 5);
  ASSERT_EQ(with.views.size(), 2u);
  EXPECT_TRUE(with.views[1].closed_eyes);
  EXPECT_GT(with.views[1].seen_texels, 100);
  // The vertices an eyeBlink moves by 0.5 mm or more, and their neighbours (whose surroundings it
  // stretches).
  std::vector<char> moved(static_cast<size_t>(model.num_vertices()), 0), lid_vertex = moved;
  for (int v = 0; v < model.num_vertices(); ++v)
    for (const char* name : {"eyeBlinkLeft", "eyeBlinkRight"})
      if (model.expression_basis.block(3 * v, arkit_blendshape_index(name), 3, 1).norm() >= 0.0005f) moved[static_cast<size_t>(v)] = 1;
  for (const auto& t : model.triangles)
    if (moved[static_cast<size_t>(t[0])] || moved[static_cast<size_t>(t[1])] || moved[static_cast<size_t>(t[2])])
      for (int32_t v : t) lid_vertex[static_cast<size_t>(v)] = 1;
  int gained = 0, gained_off_the_lids = 0;
  for (int j = 0; j < layout->height; ++j)
    for (int i = 0; i < layout->width; ++i) {
      const size_t texel = static_cast<size_t>(j) * static_cast<size_t>(layout->width) + static_cast<size_t>(i);
      if (!(with.seen.at<float>(j, i) > alone.seen.at<float>(j, i) + 1e-6f)) continue;
      ++gained;
      bool on_lid = false;
      for (size_t k = 0; k < 3; ++k) on_lid = on_lid || lid_vertex[static_cast<size_t>(layout->vertices[3 * texel + k])];
      gained_off_the_lids += !on_lid;
    }
  RecordProperty("texels_the_closed_eyes_view_adds", gained);
  EXPECT_EQ(gained, with.views[1].seen_texels);
  EXPECT_EQ(gained_off_the_lids, 0);

  // The pipeline: a blink facing the camera becomes the closed-eyes view.
  ReenactmentOptions o;
  o.use_ground_truth_target = true;
  o.albedo_texture.size = 512;
  ReenactmentPipeline pipeline(model, o);
  const gpu::PinholeCamera small = test_camera(160, 120);
  for (int index = 0; index < 10; ++index) {  // (the texture is first built at the 8th frame)
    capture::RgbdFrame f = frame_turned(index == 3 ? 0.f : 1.f, index, small);
    if (index == 3) {
      f.ground_truth.params->delta[arkit_blendshape_index("eyeBlinkLeft")] = 0.9f;
      f.ground_truth.params->delta[arkit_blendshape_index("eyeBlinkRight")] = 0.9f;
      f.color = render_target(*f.ground_truth.params, small);
    }
    EXPECT_TRUE(pipeline.Process(f, nullptr).reenacted);
  }
  const PipelineSummary s = pipeline.summary();
  const auto closed = std::find_if(s.albedo_texture_views.begin(), s.albedo_texture_views.end(),
                                   [](const AlbedoTexture::ViewInfo& v) { return v.closed_eyes; });
  ASSERT_NE(closed, s.albedo_texture_views.end()) << s.albedo_texture_views.size() << " views, none with the eyes closed";
  EXPECT_EQ(closed->frame_index, 3);
}

// In the background (the live session), the build runs beside the frames and a later frame takes
// it: the same views, and the frames keep coming meanwhile.
TEST(AlbedoTextureTest, ABackgroundBuildIsTakenByALaterFrame) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(160, 120);
  ReenactmentOptions o;
  o.use_ground_truth_target = true;
  o.albedo_texture.size = 1024;
  o.albedo_texture.background = true;
  ReenactmentPipeline pipeline(*test_model(), o);
  int index = 0;
  auto process = [&](float yaw) { EXPECT_TRUE(pipeline.Process(frame_turned(yaw, index++, cam), nullptr).reenacted); };
  for (float yaw : {3.f, 0.f, -20.f, -18.f, 20.f, 17.f, 1.f, 0.f, 0.f}) process(yaw);
  // The ninth tracked frame started the build; frames go on until one takes it (at most 10 s).
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (pipeline.summary().albedo_texture_builds == 0 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    process(0.f);
  }
  const PipelineSummary s = pipeline.summary();
  ASSERT_EQ(s.albedo_texture_builds, 1) << s.albedo_texture_note;
  ASSERT_EQ(s.albedo_texture_views.size(), 3u);
  EXPECT_EQ(s.albedo_texture_views[0].frame_index, 1);
  EXPECT_GT(s.albedo_texture_ms, 0.0);
  // A recalibration while nothing is in flight, and the pipeline's end with one in flight, are safe.
  pipeline.RequestCalibration();
  process(0.f);
}

// A layout of another model is refused, not read out of bounds.
TEST(AlbedoTextureTest, UnwrapRefusesALayoutOfAnotherModel) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(160, 120);
  const FaceCompositor fc(*test_model(), ReenactmentOptions{});
  AlbedoTextureLayout other = *AlbedoTextureLayout::ForModel(*test_model(), 256);
  other.textured.pop_back();
  EXPECT_THROW(fc.UnwrapAlbedo(render_target(test_face(0.4f), cam), cam, test_face(0.4f), other), Error);
  EXPECT_THROW(fc.UnwrapAlbedo(cv::Mat(10, 10, CV_8UC3), cam, test_face(0.4f), other), Error);
}

}  // namespace
}  // namespace face_reenact::reenact
