// The renderer on the real face model (env FR_MODEL: the project's test command builds it
// first). Fails with a clear message when the model file is missing.
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>

#include "face_reenact/common/error.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/gpu/renderer.h"
#include "face_reenact/model/model_file.h"
#include "gpu_renderer_compare.h"
#include "gpu_test_support.h"

namespace face_reenact::gpu {
namespace {

using testing::ValidatedGpuTest;

const FaceModel& face_model() {
  static const FaceModel model = [] {
    const char* path = std::getenv("FR_MODEL");
    if (!path || !*path) {
      ADD_FAILURE() << "FR_MODEL is not set: run the tests through ctest (which sets it) after building the face model";
      return FaceModel{};
    }
    if (!std::filesystem::exists(path)) {
      ADD_FAILURE() << "face model " << path << " is missing: build it first with `face-reenact model build`";
      return FaceModel{};
    }
    return load_face_model(path);
  }();
  return model;
}

// Parameters drawn from the model's priors: alpha_i ~ N(0, sigma_id_i), beta_i ~ N(0, sigma_alb_i),
// delta_i ~ U(0, 0.6), a head turn of up to ~25 degrees, and random SH lighting.
FaceParameters random_face_parameters(const FaceModel& m, std::mt19937& rng) {
  std::normal_distribution<float> gauss(0.f, 1.f);
  std::uniform_real_distribution<float> unit(0.f, 1.f);
  FaceParameters p = frontal_pose(0.55f);
  p.alpha = Eigen::VectorXf(m.num_identity());
  for (int i = 0; i < m.num_identity(); ++i) p.alpha[i] = m.identity_sigma[i] * gauss(rng);
  p.beta = Eigen::VectorXf(m.num_albedo());
  for (int i = 0; i < m.num_albedo(); ++i) p.beta[i] = m.albedo_sigma[i] * gauss(rng);
  p.delta = Eigen::VectorXf(m.num_expression());
  for (int i = 0; i < m.num_expression(); ++i) p.delta[i] = 0.6f * unit(rng);
  p.euler += Eigen::Vector3f(0.15f * gauss(rng), 0.25f * gauss(rng), 0.1f * gauss(rng));
  p.translation += Eigen::Vector3f(0.03f * gauss(rng), 0.03f * gauss(rng), 0.1f * gauss(rng));
  for (int c = 0; c < 3; ++c) {
    p.gamma[c * 9] = 3.0f + 0.3f * gauss(rng);
    for (int k = 1; k < 9; ++k) p.gamma[c * 9 + k] = 0.3f * gauss(rng);
  }
  return p;
}

// The CPU rasteriser splits its work over threads (triangle set-up, then bands of rows); every
// pixel must still see the same triangles in the same order, so the G-buffer is bit-identical.
TEST(CpuRendererThreads, GBufferIsBitIdenticalOnAnyThreadCount) {
  if (face_model().num_vertices() == 0) GTEST_FAIL() << "no face model (see the failure above)";
  const CpuRenderer cpu(RenderModel::FromFaceModel(face_model()));
  std::mt19937 rng(4242);
  for (int trial = 0; trial < 3; ++trial) {
    const VertexState state = cpu.evaluate(random_face_parameters(face_model(), rng));
    for (int level = 0; level < 3; ++level) {
      const PinholeCamera camera = PinholeCamera{}.Downsampled(level);
      GBuffer one;
      cpu.rasterize(state, camera, RenderOptions{}, &one, 1);
      ASSERT_GT(one.covered_count(), 100u);
      for (int threads : {2, 3, 8}) {
        GBuffer many;
        cpu.rasterize(state, camera, RenderOptions{}, &many, threads);
        EXPECT_EQ(many.color, one.color) << "trial " << trial << " level " << level << " threads " << threads;
        EXPECT_EQ(many.position, one.position);
        EXPECT_EQ(many.normal, one.normal);
        EXPECT_EQ(many.barycentric, one.barycentric);
        EXPECT_EQ(many.triangle, one.triangle);
        EXPECT_EQ(many.vertices, one.vertices);
      }
    }
  }
}

// A draw without normals (RenderOptions::normals: the tracker's synthesis on colour-only input,
// the frame texture's tracked geometry) or without colours (RenderOptions::colors: those and the
// gaze's eye renders, whose vertex states are unshaded) writes the same bits into every other
// field and zeros into the one left out, also into a kept buffer whose last draw had it (the
// rasteriser clears only the rectangle that draw covered).
TEST(CpuRendererFields, ADrawWithoutNormalsOrColoursGivesTheSameOtherFieldsAndZeros) {
  if (face_model().num_vertices() == 0) GTEST_FAIL() << "no face model (see the failure above)";
  const CpuRenderer cpu(RenderModel::FromFaceModel(face_model()));
  RenderOptions no_normals, no_colors;
  no_normals.normals = false;
  no_colors.colors = false;
  for (const RenderOptions& without_one : {no_normals, no_colors}) {
    const bool normals = without_one.normals;
    std::mt19937 rng(77);
    GBuffer kept;  // drawn with both, then without one, then with both, as a per-frame caller keeps it
    for (int trial = 0; trial < 3; ++trial) {
      const VertexState state = cpu.evaluate(random_face_parameters(face_model(), rng));
      const PinholeCamera camera = PinholeCamera{}.Downsampled(trial % 2);
      GBuffer with;
      cpu.rasterize(state, camera, RenderOptions{}, &with, 2);
      ASSERT_GT(with.covered_count(), 100u);
      const std::vector<float>& left_out = normals ? with.color : with.normal;
      ASSERT_NE(left_out, std::vector<float>(left_out.size(), 0.f));
      for (GBuffer* without : {&kept, static_cast<GBuffer*>(nullptr)}) {
        GBuffer fresh;
        GBuffer& g = without ? *without : fresh;
        cpu.rasterize(state, camera, without_one, &g, 2);
        EXPECT_EQ(g.position, with.position) << "trial " << trial << (normals ? ", no colours" : ", no normals");
        EXPECT_EQ(g.barycentric, with.barycentric);
        EXPECT_EQ(g.triangle, with.triangle);
        EXPECT_EQ(g.vertices, with.vertices);
        EXPECT_EQ(normals ? g.normal : g.color, normals ? with.normal : with.color);
        EXPECT_EQ(normals ? g.color : g.normal, std::vector<float>(left_out.size(), 0.f));
      }
      cpu.rasterize(state, camera, RenderOptions{}, &kept, 2);
      EXPECT_EQ(kept.normal, with.normal);
      EXPECT_EQ(kept.color, with.color);
    }
  }
}

// The CPU renderer sums each vertex's expression over the blendshapes that move it
// (RenderModel::expression_columns): the same positions as the dense product, and the index is
// the real model's sparsity (a vertex moved by most of the 52 would make it no faster).
TEST(CpuRendererExpression, TheVertexSumsOverTheirOwnBlendshapesGiveTheDenseProduct) {
  if (face_model().num_vertices() == 0) GTEST_FAIL() << "no face model (see the failure above)";
  const RenderModel model = RenderModel::FromFaceModel(face_model());
  const VertexColumns& ec = model.expression_columns;
  const int n = model.num_vertices();
  ASSERT_EQ(ec.begin.size(), static_cast<size_t>(n) + 1);
  size_t still = 0;
  for (int v = 0; v < n; ++v) still += ec.begin[static_cast<size_t>(v)] == ec.begin[static_cast<size_t>(v) + 1];
  EXPECT_LT(ec.column.size(), static_cast<size_t>(n) * model.expression_basis.cols() / 3)
      << "the blendshapes are expected to be local";
  EXPECT_GT(still, static_cast<size_t>(n) / 10) << "the back of the head moves with no expression";

  const CpuRenderer cpu(model);
  std::mt19937 rng(5150);
  for (int trial = 0; trial < 3; ++trial) {
    const FaceParameters p = random_face_parameters(face_model(), rng);
    const VertexState state = cpu.evaluate(p, nullptr, trial + 1);
    const Eigen::VectorXf dense = model.mean_shape + model.identity_basis * p.alpha + model.expression_basis * p.delta;
    ASSERT_EQ(state.model_positions.size(), dense.size());
    for (Eigen::Index i = 0; i < dense.size(); ++i)
      ASSERT_NEAR(state.model_positions[i], dense[i], 2e-6f) << "trial " << trial << " row " << i;
  }
}

// An index made before the basis changed no longer describes it: the model is refused with the
// reason rather than rendered with the old blendshapes.
TEST(CpuRendererExpression, AModelWhoseIndexIsStaleIsRefused) {
  if (face_model().num_vertices() == 0) GTEST_FAIL() << "no face model (see the failure above)";
  RenderModel model = RenderModel::FromFaceModel(face_model());
  std::string why;
  ASSERT_TRUE(model.IsValid(&why)) << why;
  const int still = [&] {
    for (int v = 0; v < model.num_vertices(); ++v)
      if (model.expression_columns.begin[static_cast<size_t>(v)] == model.expression_columns.begin[static_cast<size_t>(v) + 1])
        return v;
    return -1;
  }();
  ASSERT_GE(still, 0);
  model.expression_basis(3 * still + 1, 7) = 0.001f;  // a blendshape now moves a vertex the index says it does not
  EXPECT_FALSE(model.IsValid(&why));
  EXPECT_NE(why.find("IndexExpression"), std::string::npos) << why;
  EXPECT_THROW(CpuRenderer{model}, Error);
  model.IndexExpression();
  EXPECT_TRUE(model.IsValid(&why)) << why;
  model.expression_columns.xyz[0] *= 2.f;  // a listed value that is not the basis's
  EXPECT_FALSE(model.IsValid(&why));
}

class FaceModelRenderTest : public ValidatedGpuTest {
 protected:
  void SetUp() override {
    ValidatedGpuTest::SetUp();
    if (face_model().num_vertices() == 0) GTEST_FAIL() << "no face model (see the failure above)";
  }
};

TEST_F(FaceModelRenderTest, FrontalFaceCoversTheImageCentre) {
  const RenderModel model = RenderModel::FromFaceModel(face_model());
  Renderer renderer(context(), model);
  const PinholeCamera cam;
  renderer.render(frontal_pose(0.5f), cam);
  const GBuffer g = renderer.read_gbuffer();
  // A face is ~0.2 m tall: at 0.5 m and f = 525 px that is ~200 px, so thousands of pixels.
  EXPECT_GT(g.covered_count(), 10000u);
  EXPECT_LT(g.covered_count(), 640u * 480u / 2);
  // The model origin (between the eyes) projects to the principal point, which is covered, and
  // the surface there lies a little in front of the origin (the bridge of the nose).
  const size_t c = 240 * 640 + 320;
  ASSERT_GE(g.triangle[c], 0);
  EXPECT_LT(g.position[3 * c + 2], 0.5f);
  EXPECT_GT(g.position[3 * c + 2], 0.45f);
  // The face looks at the camera: normals near the centre point back towards it (n_z < 0).
  EXPECT_LT(g.normal[3 * c + 2], -0.5f);
  // The chin is below the eyes: covered pixels reach further down (larger v) than up past the
  // forehead? Not necessarily; but the face must extend both above and below the centre.
  int min_j = 480, max_j = -1;
  for (int j = 0; j < 480; ++j) {
    for (int i = 0; i < 640; ++i) {
      if (g.covered(i, j)) {
        min_j = std::min(min_j, j);
        max_j = std::max(max_j, j);
      }
    }
  }
  EXPECT_LT(min_j, 200);
  EXPECT_GT(max_j, 300);
}

TEST_F(FaceModelRenderTest, GpuMatchesCpuAtEveryPyramidLevel) {
  const RenderModel model = RenderModel::FromFaceModel(face_model());
  Renderer renderer(context(), model);
  CpuRenderer cpu(model);
  std::mt19937 rng(2015);
  for (int level = 0; level < 3; ++level) {
    const PinholeCamera cam = PinholeCamera{}.Downsampled(level);
    for (int trial = 0; trial < 3; ++trial) {
      const FaceParameters p = random_face_parameters(face_model(), rng);
      RenderOptions options;
      options.parts = trial == 2 ? kAllParts : kSkinParts;
      renderer.render(p, cam, options);
      const GBuffer gpu = renderer.read_gbuffer();
      const GBuffer ref = cpu.render(p, cam, options);
      SCOPED_TRACE("level " + std::to_string(level) + " trial " + std::to_string(trial));
      testing::expect_gbuffers_agree(gpu, ref);
    }
  }
}

TEST_F(FaceModelRenderTest, VertexStageMatchesCpu) {
  const RenderModel model = RenderModel::FromFaceModel(face_model());
  Renderer renderer(context(), model);
  CpuRenderer cpu(model);
  std::mt19937 rng(7);
  const FaceParameters p = random_face_parameters(face_model(), rng);
  renderer.render(p, PinholeCamera{});
  const VertexState gpu = renderer.read_vertex_state();
  const VertexState ref = cpu.evaluate(p);
  EXPECT_LT((gpu.model_positions - ref.model_positions).cwiseAbs().maxCoeff(), 2e-6f);
  EXPECT_LT((gpu.albedo - ref.albedo).cwiseAbs().maxCoeff(), 2e-5f);
  EXPECT_LT((gpu.camera_positions - ref.camera_positions).cwiseAbs().maxCoeff(), 2e-6f);
  // Normals of tiny or sliver triangles are the most sensitive to summation order.
  EXPECT_LT((gpu.camera_normals - ref.camera_normals).cwiseAbs().maxCoeff(), 1e-3f);
  EXPECT_LT((gpu.colors - ref.colors).cwiseAbs().maxCoeff(), 1e-3f);
}

TEST_F(FaceModelRenderTest, MouthInteriorIsSelectedByThePartMask) {
  const FaceModel& fm = face_model();
  const RenderModel model = RenderModel::FromFaceModel(fm);
  Renderer renderer(context(), model);
  // Open the jaw so the teeth and tongue are visible, and draw only those parts.
  FaceParameters p = frontal_pose(0.5f);
  p.delta = Eigen::VectorXf::Zero(fm.num_expression());
  const int jaw = arkit_blendshape_index("jawOpen");
  ASSERT_GE(jaw, 0);
  p.delta[jaw] = 1.0f;
  RenderOptions mouth;
  mouth.parts = (1u << static_cast<int>(FacePart::UpperTeeth)) | (1u << static_cast<int>(FacePart::LowerTeeth)) |
                (1u << static_cast<int>(FacePart::Tongue));
  mouth.cull_back_faces = false;
  renderer.render(p, PinholeCamera{}, mouth);
  const GBuffer g = renderer.read_gbuffer();
  EXPECT_GT(g.covered_count(), 0u);
  for (size_t q = 0; q < g.triangle.size(); ++q) {
    if (g.triangle[q] < 0) continue;
    const auto part = fm.vertex_part[fm.triangles[g.triangle[q]][0]];
    ASSERT_TRUE(part == FacePart::UpperTeeth || part == FacePart::LowerTeeth || part == FacePart::Tongue)
        << face_part_name(part);
  }
}

}  // namespace
}  // namespace face_reenact::gpu
