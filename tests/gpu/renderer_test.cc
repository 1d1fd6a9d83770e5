// The image formation model S(P) on the GPU against analytic results and against its CPU twin.
#include <cmath>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "face_reenact/common/error.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/gpu/renderer.h"
#include "gpu_renderer_compare.h"
#include "gpu_test_support.h"
#include "test_meshes.h"

namespace face_reenact::gpu {
namespace {

using testing::ValidatedGpuTest;

constexpr float kRadius = 0.1f;
constexpr float kDistance = 0.6f;

class RendererTest : public ValidatedGpuTest {};

// Faces that move across the image at 0.3 m, then one off the image (nothing drawn): what the
// tests of buffers drawn into again and again draw.
std::vector<FaceParameters> MovingFacesThenOneOffTheImage() {
  std::vector<FaceParameters> poses;
  for (float x : {0.05f, -0.06f, 0.0f}) {
    FaceParameters p = frontal_pose(0.3f);
    p.translation.x() = x;
    poses.push_back(p);
  }
  FaceParameters away = frontal_pose(kDistance);
  away.translation.x() = 5.0f;
  poses.push_back(away);
  return poses;
}

// Every channel of two G-buffers the same, bit for bit.
void ExpectSameGBuffers(const GBuffer& got, const GBuffer& expected, const std::string& what) {
  EXPECT_EQ(got.color, expected.color) << what;
  EXPECT_EQ(got.position, expected.position) << what;
  EXPECT_EQ(got.normal, expected.normal) << what;
  EXPECT_EQ(got.barycentric, expected.barycentric) << what;
  EXPECT_EQ(got.triangle, expected.triangle) << what;
  EXPECT_EQ(got.vertices, expected.vertices) << what;
}

// A sphere of radius r centred at distance D on the optical axis projects to a disc of radius
// f r / sqrt(D^2 - r^2) around the principal point; its nearest point is at depth D - r with
// normal (0, 0, -1).
TEST_F(RendererTest, SphereProjectsToTheExpectedDisc) {
  const RenderModel sphere = testing::make_icosphere(kRadius, 4);
  Renderer renderer(context(), sphere);
  PinholeCamera cam;
  FaceParameters p = frontal_pose(kDistance);
  p.euler.setZero();
  renderer.render(p, cam);
  const GBuffer g = renderer.read_gbuffer();
  const double rho = cam.fx * kRadius / std::sqrt(kDistance * kDistance - kRadius * kRadius);
  int wrong_inside = 0, wrong_outside = 0;
  for (int j = 0; j < cam.height; ++j) {
    for (int i = 0; i < cam.width; ++i) {
      const double r = std::hypot(i - cam.cx, j - cam.cy);
      // The tessellated sphere is inscribed, so its silhouette is at most ~0.1% smaller.
      if (r < rho - 1.0 && !g.covered(i, j)) ++wrong_inside;
      if (r > rho + 1.0 && g.covered(i, j)) ++wrong_outside;
    }
  }
  EXPECT_EQ(wrong_inside, 0);
  EXPECT_EQ(wrong_outside, 0);
  const double area = M_PI * rho * rho;
  EXPECT_NEAR(static_cast<double>(g.covered_count()), area, 0.02 * area);

  // Centre pixel (319.5, 239.5) lies between four pixels; take (320, 240).
  const size_t c = 240 * 640 + 320;
  EXPECT_NEAR(g.position[3 * c + 2], kDistance - kRadius, 2e-4);
  EXPECT_NEAR(g.normal[3 * c + 2], -1.0f, 2e-3);
  // Away from the centre, the interpolated normal still points from the sphere centre.
  for (int j = 150; j < 330; j += 7) {
    for (int i = 230; i < 410; i += 7) {
      if (!g.covered(i, j)) continue;
      const size_t q = static_cast<size_t>(j) * 640 + i;
      Eigen::Vector3f x(g.position[3 * q], g.position[3 * q + 1], g.position[3 * q + 2]);
      Eigen::Vector3f n(g.normal[3 * q], g.normal[3 * q + 1], g.normal[3 * q + 2]);
      const Eigen::Vector3f radial = (x - Eigen::Vector3f(0, 0, kDistance)).normalized();
      EXPECT_GT(n.dot(radial), 0.999f) << "pixel " << i << "," << j;
      EXPECT_NEAR((x - Eigen::Vector3f(0, 0, kDistance)).norm(), kRadius, 0.002f * kRadius);
    }
  }
}

TEST_F(RendererTest, BackFaceCullingKeepsTheNearHemisphere) {
  const RenderModel sphere = testing::make_icosphere(kRadius, 3);
  Renderer renderer(context(), sphere);
  FaceParameters p = frontal_pose(kDistance);
  RenderOptions no_cull;
  no_cull.cull_back_faces = false;
  renderer.render(p, PinholeCamera{}, no_cull);
  const GBuffer both = renderer.read_gbuffer();
  renderer.render(p, PinholeCamera{});
  const GBuffer front = renderer.read_gbuffer();
  // The depth test already hides the far side, so culling must not change the picture.
  EXPECT_EQ(both.covered_count(), front.covered_count());
  EXPECT_NEAR(front.depth(320, 240), kDistance - kRadius, 1e-3);
  // Seen from inside (camera at the centre is impossible: near plane), test the opposite: a
  // sphere around the camera shows only back faces, so culling empties it.
  FaceParameters inside = p;
  inside.translation = Eigen::Vector3f(0, 0, 0);
  RenderModel big = testing::make_icosphere(5.0f, 2);
  Renderer big_renderer(context(), big);
  big_renderer.render(inside, PinholeCamera{}, no_cull);
  EXPECT_EQ(big_renderer.read_gbuffer().covered_count(), 640u * 480u);
  big_renderer.render(inside, PinholeCamera{});
  EXPECT_EQ(big_renderer.read_gbuffer().covered_count(), 0u);
}

// Two spheres overlapping in the image: the nearer one must win the depth test whichever is
// drawn first, on the GPU and on the CPU.
TEST_F(RendererTest, DepthTestKeepsTheNearerSurfaceInEitherDrawOrder) {
  const RenderModel big = testing::make_icosphere(kRadius, 3, 0.2f);
  const RenderModel small = testing::make_icosphere(0.5f * kRadius, 3, 0.8f);
  FaceParameters p = frontal_pose(kDistance);
  p.euler.setZero();  // model frame = camera frame
  for (bool near_first : {true, false}) {
    // The small sphere sits 0.25 m in front of the big one (towards the camera).
    const RenderModel scene = near_first ? testing::concatenate(small, big, Eigen::Vector3f(0, 0, 0.25f))
                                         : testing::concatenate(big, small, Eigen::Vector3f(0, 0, -0.25f));
    FaceParameters q = p;
    if (near_first) q.translation.z() -= 0.25f;
    for (bool cull : {true, false}) {
      RenderOptions options;
      options.cull_back_faces = cull;
      Renderer renderer(context(), scene);
      renderer.render(q, PinholeCamera{}, options);
      const GBuffer g = renderer.read_gbuffer();
      const GBuffer c = CpuRenderer(scene).render(q, PinholeCamera{}, options);
      const size_t centre = 240 * 640 + 320;
      const float near_z = kDistance - 0.25f - 0.5f * kRadius;
      SCOPED_TRACE(std::string(near_first ? "near first" : "near last") + (cull ? ", culling" : ", no culling"));
      EXPECT_NEAR(g.position[3 * centre + 2], near_z, 1e-3);
      EXPECT_NEAR(c.position[3 * centre + 2], near_z, 1e-3);
      EXPECT_NEAR(g.color[3 * centre], 0.8f, 1e-4);
      testing::expect_gbuffers_agree(g, c);
    }
  }
}

TEST_F(RendererTest, DcOnlyLightingShadesUniformly) {
  const RenderModel sphere = testing::make_icosphere(kRadius, 3, 0.4f);
  Renderer renderer(context(), sphere);
  FaceParameters p = frontal_pose(kDistance);
  p.gamma = ambient_sh(Eigen::Vector3f(0.9f, 0.6f, 0.3f));
  renderer.render(p, PinholeCamera{});
  const GBuffer g = renderer.read_gbuffer();
  ASSERT_GT(g.covered_count(), 1000u);
  const float expected[3] = {0.4f * 0.9f, 0.4f * 0.6f, 0.4f * 0.3f};
  for (size_t q = 0; q < g.triangle.size(); ++q) {
    if (g.triangle[q] < 0) continue;
    for (int c = 0; c < 3; ++c) ASSERT_NEAR(g.color[3 * q + c], expected[c], 1e-5) << "pixel " << q;
  }
}

TEST_F(RendererTest, DirectionalShLightingFollowsTheNormal) {
  // gamma with only the y3 = 0.488603 x term: colour = albedo * k * 0.488603 * n_x, so the
  // right half of the sphere is lit and the left half negative.
  const RenderModel sphere = testing::make_icosphere(kRadius, 3, 1.0f);
  Renderer renderer(context(), sphere);
  FaceParameters p = frontal_pose(kDistance);
  p.gamma.fill(0.f);
  for (int c = 0; c < 3; ++c) p.gamma[c * 9 + 3] = 1.0f;
  renderer.render(p, PinholeCamera{});
  const GBuffer g = renderer.read_gbuffer();
  const VertexState vs = renderer.read_vertex_state();
  for (int v = 0; v < sphere.num_vertices(); ++v) {
    ASSERT_NEAR(vs.colors[3 * v], 0.488603f * vs.camera_normals[3 * v], 1e-5);
  }
  const size_t right = 240 * 640 + 360, left = 240 * 640 + 280;
  EXPECT_GT(g.color[3 * right], 0.1f);
  EXPECT_LT(g.color[3 * left], -0.1f);
}

TEST_F(RendererTest, BarycentricsSumToOneAndReproducePositions) {
  const RenderModel model = testing::make_deformable_sphere(kRadius, 3, 5, 4, 3, 7);
  Renderer renderer(context(), model);
  FaceParameters p = frontal_pose(kDistance);
  p.alpha = Eigen::VectorXf::Constant(5, 1.0f);
  p.delta = Eigen::VectorXf::Constant(4, 0.5f);
  p.euler += Eigen::Vector3f(0.2f, -0.3f, 0.1f);
  renderer.render(p, PinholeCamera{});
  const GBuffer g = renderer.read_gbuffer();
  const VertexState vs = renderer.read_vertex_state();
  ASSERT_GT(g.covered_count(), 1000u);
  for (size_t q = 0; q < g.triangle.size(); ++q) {
    if (g.triangle[q] < 0) continue;
    const auto& tri = model.triangles[g.triangle[q]];
    Eigen::Vector3f x = Eigen::Vector3f::Zero();
    float sum = 0.f;
    for (int k = 0; k < 3; ++k) {
      ASSERT_EQ(g.vertices[3 * q + k], tri[k]) << "pixel " << q;
      const float b = g.barycentric[3 * q + k];
      // Coverage uses 1/256-pixel snapped vertices, interpolation the exact plane: a pixel just
      // inside the snapped triangle may sit a hair outside the exact one.
      ASSERT_GE(b, -2e-3f);
      ASSERT_LE(b, 1.0f + 2e-3f);
      sum += b;
      x += b * vs.camera_positions.segment<3>(3 * tri[k]);
    }
    ASSERT_NEAR(sum, 1.0f, 1e-5f) << "pixel " << q;
    for (int c = 0; c < 3; ++c) ASSERT_NEAR(g.position[3 * q + c], x[c], 1e-5f) << "pixel " << q;
  }
}

TEST_F(RendererTest, VertexStageMatchesCpu) {
  const RenderModel model = testing::make_deformable_sphere(kRadius, 3, 8, 6, 4, 11);
  Renderer renderer(context(), model);
  CpuRenderer cpu(model);
  std::mt19937 rng(5);
  const FaceParameters p = testing::random_parameters(model, kDistance, rng);
  renderer.render(p, PinholeCamera{});
  const VertexState gpu = renderer.read_vertex_state();
  const VertexState ref = cpu.evaluate(p);
  EXPECT_LT((gpu.model_positions - ref.model_positions).cwiseAbs().maxCoeff(), 1e-6f);
  EXPECT_LT((gpu.albedo - ref.albedo).cwiseAbs().maxCoeff(), 1e-5f);
  EXPECT_LT((gpu.camera_positions - ref.camera_positions).cwiseAbs().maxCoeff(), 1e-6f);
  EXPECT_LT((gpu.camera_normals - ref.camera_normals).cwiseAbs().maxCoeff(), 1e-5f);
  EXPECT_LT((gpu.colors - ref.colors).cwiseAbs().maxCoeff(), 1e-5f);
}

// The identity pass is cached: changing only delta or the pose must not re-run it, and changing
// alpha or beta must (the output follows the new values).
TEST_F(RendererTest, IdentityPassRunsOnlyWhenAlphaOrBetaChange) {
  const RenderModel model = testing::make_deformable_sphere(kRadius, 3, 6, 4, 3, 21);
  Renderer renderer(context(), model);
  CpuRenderer cpu(model);
  std::mt19937 rng(9);
  FaceParameters p = testing::random_parameters(model, kDistance, rng);
  EXPECT_TRUE(renderer.render(p, PinholeCamera{}).identity_updated);
  FaceParameters q = p;
  q.delta *= 0.5f;
  q.euler.y() += 0.1f;
  EXPECT_FALSE(renderer.render(q, PinholeCamera{}).identity_updated);
  auto expect_matches_cpu = [&](const FaceParameters& params) {
    const VertexState gpu = renderer.read_vertex_state();
    const VertexState ref = cpu.evaluate(params);
    EXPECT_LT((gpu.model_positions - ref.model_positions).cwiseAbs().maxCoeff(), 1e-6f);
    EXPECT_LT((gpu.albedo - ref.albedo).cwiseAbs().maxCoeff(), 1e-5f);
    EXPECT_LT((gpu.colors - ref.colors).cwiseAbs().maxCoeff(), 1e-5f);
  };
  expect_matches_cpu(q);
  q.alpha[2] += 1.0f;
  EXPECT_TRUE(renderer.render(q, PinholeCamera{}).identity_updated);
  expect_matches_cpu(q);
  q.beta[0] -= 0.5f;
  EXPECT_TRUE(renderer.render(q, PinholeCamera{}).identity_updated);
  expect_matches_cpu(q);
  // A shorter alpha equals the same alpha padded with zeros: no re-run.
  FaceParameters r = q;
  r.alpha.conservativeResize(r.alpha.size() + 0);
  EXPECT_FALSE(renderer.render(r, PinholeCamera{}).identity_updated);
  FaceParameters zero_tail = q;
  zero_tail.alpha[5] = 0.f;
  renderer.render(zero_tail, PinholeCamera{});
  FaceParameters shorter = zero_tail;
  shorter.alpha.conservativeResize(5);
  EXPECT_FALSE(renderer.render(shorter, PinholeCamera{}).identity_updated);
  expect_matches_cpu(shorter);
}

class RendererPyramidTest : public RendererTest, public ::testing::WithParamInterface<int> {};

TEST_P(RendererPyramidTest, GpuMatchesCpuOnRandomParameters) {
  const int level = GetParam();
  const RenderModel model = testing::make_deformable_sphere(kRadius, 4, 10, 8, 5, 1234);
  Renderer renderer(context(), model);
  CpuRenderer cpu(model);
  const PinholeCamera cam = PinholeCamera{}.Downsampled(level);
  std::mt19937 rng(100 + level);
  for (int trial = 0; trial < 8; ++trial) {
    const FaceParameters p = testing::random_parameters(model, kDistance, rng);
    RenderOptions options;
    options.parts = trial % 2 ? kAllParts : kSkinParts;
    renderer.render(p, cam, options);
    const GBuffer gpu = renderer.read_gbuffer();
    const GBuffer ref = cpu.render(p, cam, options);
    SCOPED_TRACE("level " + std::to_string(level) + " trial " + std::to_string(trial));
    testing::expect_gbuffers_agree(gpu, ref);
  }
}

INSTANTIATE_TEST_SUITE_P(Levels, RendererPyramidTest, ::testing::Values(0, 1, 2));

TEST_F(RendererTest, PartMaskSelectsTriangles) {
  const RenderModel model = testing::make_deformable_sphere(kRadius, 3, 0, 0, 0, 3);
  Renderer renderer(context(), model);
  const FaceParameters p = frontal_pose(kDistance);
  RenderOptions skin, all, tongue_only;
  all.parts = kAllParts;
  tongue_only.parts = 1u << 6;
  const auto t_skin = renderer.render(p, PinholeCamera{}, skin);
  const size_t n_skin = renderer.read_gbuffer().covered_count();
  const auto t_all = renderer.render(p, PinholeCamera{}, all);
  const size_t n_all = renderer.read_gbuffer().covered_count();
  renderer.render(p, PinholeCamera{}, tongue_only);
  const GBuffer g = renderer.read_gbuffer();
  EXPECT_LT(t_skin.drawn_triangles, t_all.drawn_triangles);
  EXPECT_EQ(t_all.drawn_triangles, model.triangles.size());
  EXPECT_LT(n_skin, n_all);
  EXPECT_GT(g.covered_count(), 0u);
  // The part with model y > 0.5 r is, after the rx = pi flip, in the upper image half (y < cy).
  for (int j = 0; j < 480; ++j) {
    for (int i = 0; i < 640; ++i) {
      if (g.covered(i, j)) ASSERT_LT(j, 240) << i << "," << j;
    }
  }
  EXPECT_THROW(renderer.render(p, PinholeCamera{}, RenderOptions{1u << 20, true}), Error);
}

TEST_F(RendererTest, NonFiniteParametersAreRejected) {
  const RenderModel model = testing::make_deformable_sphere(kRadius, 2, 3, 3, 3, 9);
  Renderer renderer(context(), model);
  CpuRenderer cpu(model);
  const float bad_values[] = {std::nanf(""), INFINITY, -INFINITY};
  for (float bad : bad_values) {
    std::vector<FaceParameters> cases(6, frontal_pose(kDistance));
    cases[0].alpha = Eigen::VectorXf::Constant(3, bad);
    cases[1].beta = Eigen::VectorXf::Constant(1, bad);
    cases[2].delta = Eigen::VectorXf::Constant(2, bad);
    cases[3].gamma[4] = bad;
    cases[4].euler.y() = bad;
    cases[5].translation.z() = bad;
    for (size_t i = 0; i < cases.size(); ++i) {
      try {
        renderer.render(cases[i], PinholeCamera{});
        FAIL() << "case " << i << " was accepted";
      } catch (const Error& e) {
        EXPECT_NE(std::string(e.what()).find("NaN or infinity"), std::string::npos) << e.what();
      }
      EXPECT_THROW(cpu.render(cases[i], PinholeCamera{}), Error);
    }
  }
  FaceParameters too_many = frontal_pose(kDistance);
  too_many.alpha = Eigen::VectorXf::Zero(4);
  EXPECT_THROW(renderer.render(too_many, PinholeCamera{}), Error);
  PinholeCamera bad_cam;
  bad_cam.fx = std::nanf("");
  EXPECT_THROW(renderer.render(frontal_pose(kDistance), bad_cam), Error);
  bad_cam = PinholeCamera{};
  bad_cam.width = 0;
  EXPECT_THROW(renderer.render(frontal_pose(kDistance), bad_cam), Error);
  // The renderer still works after rejecting input.
  EXPECT_NO_THROW(renderer.render(frontal_pose(kDistance), PinholeCamera{}));
  EXPECT_GT(renderer.read_gbuffer().covered_count(), 0u);
}

TEST_F(RendererTest, OffScreenAndBehindCameraGiveAnEmptyMask) {
  const RenderModel model = testing::make_icosphere(kRadius, 3);
  Renderer renderer(context(), model);
  CpuRenderer cpu(model);
  std::vector<Eigen::Vector3f> places = {{5.0f, 0, kDistance},    // far to the right
                                         {0, -5.0f, kDistance},   // far above
                                         {0, 0, -kDistance},      // behind the camera
                                         {0, 0, 0.0f},            // around the camera centre
                                         {0, 0, 100.0f},          // beyond the far plane
                                         {1e30f, 1e30f, 1e30f},   // absurd but finite
                                         // In the depth range but billions of pixels aside: the CPU
                                         // rasteriser's box overflowed its ints and crashed.
                                         {1e7f, 0, kDistance},
                                         {-1e7f, 0, kDistance},
                                         {0, 1e7f, kDistance}};
  for (const auto& t : places) {
    FaceParameters p = frontal_pose(kDistance);
    p.translation = t;
    renderer.render(p, PinholeCamera{});
    const GBuffer g = renderer.read_gbuffer();
    EXPECT_EQ(g.covered_count(), 0u) << t.transpose();
    for (float v : g.color) ASSERT_EQ(v, 0.f);
    EXPECT_EQ(cpu.render(p, PinholeCamera{}).covered_count(), 0u) << t.transpose();
  }
}

// The reusing overload (per-frame callers keep one G-buffer) gives exactly what a fresh buffer
// gets: nothing of the previous image survives, whatever the sizes.
TEST(CpuRendererTest, RasterizingIntoAReusedBufferLeavesNothingOfThePreviousImage) {
  const RenderModel model = testing::make_icosphere(kRadius, 3);
  const CpuRenderer cpu(model);
  const RenderOptions options;
  FaceParameters near = frontal_pose(0.3f);
  near.translation.x() = 0.05f;
  FaceParameters far = frontal_pose(kDistance);
  far.translation.y() = -0.08f;
  PinholeCamera small = PinholeCamera{};
  small.width = 160;
  small.height = 120;
  small.fx = small.fy = 131.25f;
  small.cx = 79.5f;
  small.cy = 59.5f;
  GBuffer reused;
  for (const PinholeCamera& first : {PinholeCamera{}, small}) {
    cpu.rasterize(cpu.evaluate(near), first, options, &reused);
    ASSERT_GT(reused.covered_count(), 0u);
    for (const PinholeCamera& second : {PinholeCamera{}, small}) {
      GBuffer buffer = reused;
      cpu.rasterize(cpu.evaluate(far), second, options, &buffer);
      const GBuffer fresh = cpu.rasterize(cpu.evaluate(far), second, options);
      ASSERT_GT(fresh.covered_count(), 0u);
      EXPECT_EQ(buffer.width, fresh.width);
      EXPECT_EQ(buffer.height, fresh.height);
      EXPECT_EQ(buffer.color, fresh.color);
      EXPECT_EQ(buffer.position, fresh.position);
      EXPECT_EQ(buffer.normal, fresh.normal);
      EXPECT_EQ(buffer.barycentric, fresh.barycentric);
      EXPECT_EQ(buffer.triangle, fresh.triangle);
      EXPECT_EQ(buffer.vertices, fresh.vertices);
    }
  }
}

// Drawing again into the same buffer clears only what the last draw drew (GBuffer::drawn):
// a sequence of poses that move the face about, leave the image and come back, each drawn into
// one buffer, equals each drawn into a fresh one; so does a draw after the buffer was moved, and
// after Resize.
TEST(CpuRendererTest, DrawingIntoTheSameBufferAgainEqualsAFreshBuffer) {
  const RenderModel model = testing::make_icosphere(kRadius, 3);
  const CpuRenderer cpu(model);
  const RenderOptions options;
  std::vector<FaceParameters> poses = MovingFacesThenOneOffTheImage();
  FaceParameters far = frontal_pose(kDistance);
  far.translation.y() = -0.08f;
  poses.push_back(far);
  poses.push_back(poses[0]);
  auto expect_fresh = [&](const GBuffer& buffer, const FaceParameters& p, size_t k) {
    ExpectSameGBuffers(buffer, cpu.rasterize(cpu.evaluate(p), PinholeCamera{}, options), "pose " + std::to_string(k));
  };
  GBuffer buffer;
  for (size_t k = 0; k < poses.size(); ++k) {
    cpu.rasterize(cpu.evaluate(poses[k]), PinholeCamera{}, options, &buffer, 2);
    expect_fresh(buffer, poses[k], k);
    EXPECT_EQ(buffer.covered_count() == 0, k == 3) << "pose " << k;
  }
  GBuffer moved = std::move(buffer);
  cpu.rasterize(cpu.evaluate(poses[1]), PinholeCamera{}, options, &moved);
  expect_fresh(moved, poses[1], 1);
  // Resize gives a cleared buffer of the same size; a caller may then write any pixel.
  moved.Resize(moved.width, moved.height);
  moved.triangle.back() = 7;
  moved.color.front() = 1.f;
  cpu.rasterize(cpu.evaluate(poses[2]), PinholeCamera{}, options, &moved);
  expect_fresh(moved, poses[2], 2);
}

TEST_F(RendererTest, ReadbackBeforeRenderIsAnError) {
  Renderer renderer(context(), testing::make_icosphere(kRadius, 1));
  EXPECT_THROW(renderer.read_gbuffer(), Error);
  EXPECT_THROW(renderer.targets(), Error);
}

TEST_F(RendererTest, TargetsStayOnTheGpuPerResolution) {
  Renderer renderer(context(), testing::make_icosphere(kRadius, 2));
  const PinholeCamera full;
  renderer.render(frontal_pose(kDistance), full);
  const VkImage full_ids = renderer.targets().ids.handle();
  EXPECT_EQ(renderer.targets().ids.layout, VK_IMAGE_LAYOUT_GENERAL);
  renderer.render(frontal_pose(kDistance), full.Downsampled(2));
  EXPECT_EQ(renderer.targets().color.width(), 160u);
  EXPECT_EQ(renderer.targets().color.height(), 120u);
  renderer.render(frontal_pose(kDistance), full);
  EXPECT_EQ(renderer.targets().ids.handle(), full_ids) << "targets are cached per resolution";
}

// read_gbuffer reuses one readback buffer and the caller's GBuffer across renders: a read after
// a larger render, at another pose, must equal a fresh read, with nothing of the earlier image.
TEST_F(RendererTest, ReusedReadbackEqualsAFreshReadAfterALargerRender) {
  Renderer renderer(context(), testing::make_icosphere(kRadius, 2));
  const PinholeCamera full;
  GBuffer reused;
  renderer.render(frontal_pose(kDistance), full);
  renderer.read_gbuffer(&reused);
  ASSERT_GT(reused.covered_count(), 0u);
  FaceParameters moved = frontal_pose(kDistance);
  moved.translation.x() += 0.05f;
  renderer.render(moved, full.Downsampled(1));
  renderer.read_gbuffer(&reused);
  const GBuffer fresh = renderer.read_gbuffer();
  ASSERT_EQ(reused.width, 320);
  ASSERT_EQ(reused.height, 240);
  ExpectSameGBuffers(reused, fresh, "the reused read");
  EXPECT_GT(fresh.covered_count(), 0u);
  EXPECT_THROW(renderer.read_gbuffer(nullptr), face_reenact::Error);
}

// What the compositor reads per draw (face_compositor.cc): the box of the pixels the vertices
// project to, into one kept buffer, across poses that move the face, take it off the image and
// back, with the CPU rasteriser drawing into the same buffer between: each read equals a whole
// read of the same render, bit for bit, with nothing left of the image before.
TEST_F(RendererTest, ReadingTheProjectedBoxIntoAKeptBufferEqualsAWholeRead) {
  const RenderModel model = testing::make_icosphere(kRadius, 3);
  Renderer renderer(context(), model);
  const CpuRenderer cpu(model);
  const PinholeCamera cam;
  std::vector<FaceParameters> poses = MovingFacesThenOneOffTheImage();  // off the image: an empty box
  FaceParameters behind = frontal_pose(kDistance);
  behind.translation.z() = -kDistance;  // behind the camera: no vertex in range
  poses.push_back(behind);
  poses.push_back(poses[1]);
  GBuffer kept;
  size_t read_pixels = 0, whole_pixels = 0;
  for (size_t k = 0; k < poses.size(); ++k) {
    SCOPED_TRACE("pose " + std::to_string(k));
    const VertexState state = cpu.evaluate(poses[k]);
    const PixelBox box = ProjectedBox(state, cam, 2);
    EXPECT_EQ(box.empty(), k == 3 || k == 4);
    renderer.render(poses[k], cam);
    renderer.read_gbuffer(&kept, &box);
    ExpectSameGBuffers(kept, renderer.read_gbuffer(), "the box against the whole read");
    EXPECT_EQ(kept.covered_count() == 0, k == 3 || k == 4);
    EXPECT_EQ(kept.drawn.triangle_data, kept.triangle.data());
    if (!box.empty()) read_pixels += static_cast<size_t>(box.i1 - box.i0 + 1) * (box.j1 - box.j0 + 1);
    whole_pixels += static_cast<size_t>(cam.width) * cam.height;
    // The CPU rasteriser into the same buffer clears only what the read wrote.
    if (k == 2) {
      cpu.rasterize(cpu.evaluate(poses[0]), cam, RenderOptions(), &kept, 2);
      ExpectSameGBuffers(kept, cpu.rasterize(cpu.evaluate(poses[0]), cam, RenderOptions()), "the CPU's draw after");
    }
  }
  EXPECT_LT(read_pixels * 2, whole_pixels) << "the boxes are a part of the frames";
}

// The projected box: the vertices within the depth range, grown and clipped to the image.
TEST(ImageFormationTest, ProjectedBoxBoundsTheVerticesInRange) {
  PinholeCamera cam;  // fx 525, centre (319.5, 239.5), 640x480
  VertexState s;
  s.camera_positions.resize(9);
  s.camera_positions << 0.0f, 0.0f, 1.0f,    // (319.5, 239.5)
      0.1f, 0.05f, 0.5f,                      // (424.5, 292)
      5.0f, 5.0f, 0.01f;                      // nearer than the near plane: not drawn, not counted
  PixelBox b = ProjectedBox(s, cam, 2);
  EXPECT_EQ(b.i0, 317);
  EXPECT_EQ(b.i1, 427);
  EXPECT_EQ(b.j0, 237);
  EXPECT_EQ(b.j1, 294);
  s.camera_positions[3] = -1.0f;  // now far to the left of the image: clipped at 0
  b = ProjectedBox(s, cam, 2);
  EXPECT_EQ(b.i0, 0);
  EXPECT_EQ(b.i1, 322);
  s.camera_positions << 0.0f, 0.0f, -1.0f, 0.1f, 0.05f, 60.0f, std::nanf(""), 0.0f, 1.0f;
  EXPECT_TRUE(ProjectedBox(s, cam, 2).empty()) << "behind the camera, beyond the far plane, not a number";
  s.camera_positions << 0.0f, 0.0f, -1.0f, 5.0f, 0.0f, 1.0f, 6.0f, 0.0f, 1.0f;
  EXPECT_TRUE(ProjectedBox(s, cam, 2).empty()) << "beside the image";
  s.camera_positions << 0.0f, 0.0f, -1.0f, 0.1f, 0.05f, 60.0f, std::nanf(""), 0.0f, 1.0f;
  EXPECT_TRUE(ProjectedBox(s, cam, 2).empty()) << "behind the camera, beyond the far plane, not a number";
  EXPECT_TRUE(ProjectedBox(VertexState(), cam, 2).empty());
}

TEST_F(RendererTest, TimingsAreReported) {
  Renderer renderer(context(), testing::make_icosphere(kRadius, 3));
  const RenderTimings t = renderer.render(frontal_pose(kDistance), PinholeCamera{});
  EXPECT_GE(t.model_ms, 0.0);
  EXPECT_GE(t.shade_ms, 0.0);
  EXPECT_GT(t.raster_ms, 0.0);
  EXPECT_GE(t.gpu_total_ms, t.raster_ms);
  EXPECT_GT(t.wall_ms, 0.0);
}

TEST(CameraTest, PyramidLevelsHalveAndKeepPixelCentresAligned) {
  PinholeCamera c;
  const PinholeCamera l1 = c.Downsampled(1), l2 = c.Downsampled(2);
  EXPECT_EQ(l1.width, 320);
  EXPECT_EQ(l1.height, 240);
  EXPECT_EQ(l2.width, 160);
  EXPECT_EQ(l2.height, 120);
  EXPECT_FLOAT_EQ(l1.fx, c.fx / 2);
  // A point projecting to fine pixel u projects to coarse (u + 0.5) / 2 - 0.5.
  const float x = 0.05f, z = 0.7f;
  const float u0 = c.fx * x / z + c.cx;
  const float u1 = l1.fx * x / z + l1.cx;
  EXPECT_NEAR(u1, (u0 + 0.5f) / 2 - 0.5f, 1e-4f);
  EXPECT_THROW(c.Downsampled(-1), Error);
  std::string why;
  c.near_plane = 2.0f;
  c.far_plane = 1.0f;
  EXPECT_FALSE(c.IsValid(&why));
}

TEST(ImageFormationTest, EulerConventionIsZyx) {
  const float a = 0.3f;
  const Eigen::Matrix3f rx = rotation_from_euler({a, 0, 0});
  EXPECT_NEAR(rx(1, 1), std::cos(a), 1e-6);
  EXPECT_NEAR(rx(2, 1), std::sin(a), 1e-6);
  const Eigen::Matrix3f r = rotation_from_euler({0.1f, 0.2f, 0.3f});
  const Eigen::Matrix3f expected = rotation_from_euler({0, 0, 0.3f}) * rotation_from_euler({0, 0.2f, 0}) *
                                   rotation_from_euler({0.1f, 0, 0});
  EXPECT_LT((r - expected).cwiseAbs().maxCoeff(), 1e-6f);
  EXPECT_NEAR(r.determinant(), 1.0f, 1e-5f);
}

TEST(ImageFormationTest, ShBasisIsOrthonormalOnTheSphere) {
  // Monte-Carlo-free check: integrate y_i y_j over a fine Fibonacci sphere.
  const int n = 20000;
  Eigen::Matrix<double, 9, 9> gram = Eigen::Matrix<double, 9, 9>::Zero();
  for (int s = 0; s < n; ++s) {
    const double z = 1.0 - (2.0 * s + 1.0) / n;
    const double r = std::sqrt(1.0 - z * z);
    const double phi = s * M_PI * (3.0 - std::sqrt(5.0));
    const auto y = sh_basis(Eigen::Vector3f(r * std::cos(phi), r * std::sin(phi), z));
    for (int i = 0; i < 9; ++i) {
      for (int j = 0; j < 9; ++j) gram(i, j) += y[i] * y[j];
    }
  }
  gram *= 4.0 * M_PI / n;
  EXPECT_LT((gram - Eigen::Matrix<double, 9, 9>::Identity()).cwiseAbs().maxCoeff(), 2e-3);
}

}  // namespace
}  // namespace face_reenact::gpu
