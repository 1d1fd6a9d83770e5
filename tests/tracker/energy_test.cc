// Energy, Jacobians, gradient checker, pyramid and input validation of the tracker.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <iostream>
#include <limits>
#include <random>
#include <set>
#include <utility>

#include "face_reenact/common/error.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/tracker/energy.h"
#include "face_reenact/tracker/gradient_checker.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/solver.h"
#include "math_internal.h"
#include "tracker_test_support.h"

namespace face_reenact::tracker {
namespace {

using testing::real_model;
using testing::sphere_model;
using testing::test_camera;
using testing::true_parameters;

TEST(TrackerMath, DoubleTwinsMatchTheRendererConventions) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-3.f, 3.f);
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Vector3f e(u(rng), u(rng), u(rng));
    const Eigen::Matrix3d r = internal::rotation_with_derivatives(e.cast<double>()).r;
    EXPECT_LT((r.cast<float>() - gpu::rotation_from_euler(e)).cwiseAbs().maxCoeff(), 1e-6f);
    const Eigen::Vector3f n = Eigen::Vector3f(u(rng), u(rng), u(rng)).normalized();
    const auto a = internal::sh_basis(n.cast<double>());
    const auto b = gpu::sh_basis(n);
    for (int k = 0; k < 9; ++k) EXPECT_NEAR(a[k], b[k], 1e-6) << "basis " << k;
  }
}

TEST(TrackerMath, RotationAndShDerivativesMatchDifferences) {
  const Eigen::Vector3d e(0.3, -1.1, 2.0);
  const auto rd = internal::rotation_with_derivatives(e);
  for (int a = 0; a < 3; ++a) {
    Eigen::Vector3d ep = e, em = e;
    ep[a] += 1e-6;
    em[a] -= 1e-6;
    const Eigen::Matrix3d num =
        (internal::rotation_with_derivatives(ep).r - internal::rotation_with_derivatives(em).r) / 2e-6;
    EXPECT_LT((num - rd.d[a]).cwiseAbs().maxCoeff(), 1e-8) << "axis " << a;
  }
  const Eigen::Vector3d n(0.2, -0.5, 0.8);
  const auto g = internal::sh_basis_gradient(n);
  for (int c = 0; c < 3; ++c) {
    Eigen::Vector3d np = n, nm = n;
    np[c] += 1e-6;
    nm[c] -= 1e-6;
    const auto yp = internal::sh_basis(np), ym = internal::sh_basis(nm);
    for (int k = 0; k < 9; ++k) EXPECT_NEAR((yp[k] - ym[k]) / 2e-6, g[k][c], 1e-7);
  }
}

InputFrame flat_frame(int w, int h, float depth, float grey) {
  InputFrame f;
  f.camera = test_camera(w, h);
  f.color.assign(3 * static_cast<size_t>(w) * h, grey);
  f.depth.assign(static_cast<size_t>(w) * h, depth);
  return f;
}

TEST(TrackerPyramid, LevelsFollowTheCameraConvention) {
  InputFrame f = flat_frame(64, 48, 0.7f, 0.25f);
  f.landmarks.push_back({30, Eigen::Vector2f(10.f, 20.f), 0.9f});
  const auto levels = BuildPyramid(f, PyramidOptions{});
  ASSERT_EQ(levels.size(), 3u);
  for (int l = 0; l < 3; ++l) {
    const gpu::PinholeCamera expect = f.camera.Downsampled(l);
    EXPECT_EQ(levels[l].width(), expect.width);
    EXPECT_EQ(levels[l].height(), expect.height);
    EXPECT_FLOAT_EQ(levels[l].camera.cx, expect.cx);
    EXPECT_FLOAT_EQ(levels[l].camera.fx, expect.fx);
    for (float c : levels[l].color) ASSERT_NEAR(c, 0.25f, 1e-6f);
    for (float d : levels[l].depth) ASSERT_NEAR(d, 0.7f, 1e-6f);
    ASSERT_EQ(levels[l].landmarks.size(), 1u);
    EXPECT_FLOAT_EQ(levels[l].landmarks[0].confidence, 0.9f);
  }
  // Pixel (10, 20) is the centre of coarse pixel (4.75, 9.75) one level down.
  EXPECT_NEAR(levels[1].landmarks[0].position.x(), 4.75f, 1e-6f);
  EXPECT_NEAR(levels[1].landmarks[0].position.y(), 9.75f, 1e-6f);
}

TEST(TrackerPyramid, DepthIsNotAveragedAcrossSilhouettesOrHoles) {
  InputFrame f = flat_frame(32, 32, 0.5f, 0.5f);
  for (int j = 0; j < 32; ++j) {
    for (int i = 16; i < 32; ++i) f.depth[j * 32 + i] = 1.5f;  // background
    f.depth[j * 32 + 3] = std::nanf("");                        // a column of holes
    f.depth[j * 32 + 5] = 0.f;
  }
  const auto levels = BuildPyramid(f, PyramidOptions{});
  for (size_t l = 1; l < levels.size(); ++l) {
    for (float d : levels[l].depth) {
      EXPECT_TRUE(std::abs(d - 0.5f) < 1e-5f || std::abs(d - 1.5f) < 1e-5f) << d;
    }
  }
}

// The levels are built on several threads (row blocks): the same values for any count.
TEST(TrackerPyramid, LevelsAreTheSameOnAnyThreadCount) {
  InputFrame f = flat_frame(160, 120, 0.6f, 0.3f);
  for (int j = 0; j < 120; ++j) {
    for (int i = 0; i < 160; ++i) {
      const size_t p = static_cast<size_t>(j) * 160 + i;
      f.depth[p] = i > 100 ? 1.4f : 0.6f + 0.001f * static_cast<float>((i * 7 + j * 13) % 17);
      if ((i + 3 * j) % 29 == 0) f.depth[p] = std::nanf("");
      for (int k = 0; k < 3; ++k) f.color[3 * p + k] = static_cast<float>((i * (k + 1) + j) % 11) / 11.f;
    }
  }
  const auto one = BuildPyramid(f, PyramidOptions{}, 1);
  for (int threads : {2, 5}) {
    const auto many = BuildPyramid(f, PyramidOptions{}, threads);
    ASSERT_EQ(many.size(), one.size());
    for (size_t l = 0; l < one.size(); ++l) {
      EXPECT_EQ(many[l].color, one[l].color) << "level " << l << ", " << threads << " threads";
      // Bytes, not values: level 0 is the input itself, holes (NaN) included.
      ASSERT_EQ(many[l].depth.size(), one[l].depth.size());
      EXPECT_EQ(std::memcmp(many[l].depth.data(), one[l].depth.data(), one[l].depth.size() * sizeof(float)), 0)
          << "level " << l << ", " << threads << " threads";
    }
  }
}

// Each coarse pixel is the [1 3 3 1] / 8 kernel over the fine pixels 2i-1 .. 2i+2 (clamped at the
// border) in both directions, computed here directly, tap by tap; depth the same over the valid
// samples near the inner block's nearest one. The pyramid filters rows first (the kernel is
// separable): the same values up to rounding, on odd sizes and at every border too.
TEST(TrackerPyramid, EachCoarsePixelIsTheKernelOverItsFineBlock) {
  const int fw = 37, fh = 23;
  InputFrame f = flat_frame(fw, fh, 0.6f, 0.3f);
  for (int j = 0; j < fh; ++j) {
    for (int i = 0; i < fw; ++i) {
      const size_t p = static_cast<size_t>(j) * fw + i;
      for (int k = 0; k < 3; ++k) f.color[3 * p + k] = static_cast<float>((i * 31 + j * 17 + k * 7) % 23) / 23.f;
      f.depth[p] = i > 25 ? 1.3f : 0.6f + 0.002f * static_cast<float>((i * 5 + j * 3) % 7);
      if ((i + 2 * j) % 13 == 0) f.depth[p] = std::nanf("");
    }
  }
  const PyramidOptions options;
  const auto levels = BuildPyramid(f, options, 3);
  const InputFrame& c = levels[1];
  constexpr float kTap[4] = {1.f / 8, 3.f / 8, 3.f / 8, 1.f / 8};
  for (int j = 0; j < c.height(); ++j) {
    for (int i = 0; i < c.width(); ++i) {
      double rgb[3] = {0, 0, 0};
      float nearest = std::numeric_limits<float>::infinity();
      for (int fj : {2 * j, 2 * j + 1}) {
        for (int fi : {2 * i, 2 * i + 1}) {
          if (f.depth_valid(std::min(fi, fw - 1), std::min(fj, fh - 1))) {
            nearest = std::min(nearest, f.depth[static_cast<size_t>(std::min(fj, fh - 1)) * fw + std::min(fi, fw - 1)]);
          }
        }
      }
      double dsum = 0, dw = 0;
      for (int b = 0; b < 4; ++b) {
        for (int a = 0; a < 4; ++a) {
          const int fi = std::clamp(2 * i - 1 + a, 0, fw - 1), fj = std::clamp(2 * j - 1 + b, 0, fh - 1);
          const size_t p = static_cast<size_t>(fj) * fw + fi;
          for (int k = 0; k < 3; ++k) rgb[k] += kTap[a] * kTap[b] * f.color[3 * p + k];
          if (f.depth_valid(fi, fj) && std::abs(f.depth[p] - nearest) <= options.depth_edge_threshold) {
            dsum += kTap[a] * kTap[b] * f.depth[p];
            dw += kTap[a] * kTap[b];
          }
        }
      }
      const size_t q = static_cast<size_t>(j) * c.width() + i;
      for (int k = 0; k < 3; ++k) ASSERT_NEAR(c.color[3 * q + k], rgb[k], 1e-6) << "pixel " << i << ", " << j;
      ASSERT_NEAR(c.depth[q], dw > 0 ? dsum / dw : 0.0, 1e-6) << "pixel " << i << ", " << j;
    }
  }
}

// A schedule that starts on a coarser level never reads level 0: without it the other levels are
// the same, and level 0 keeps the frame's camera and landmarks, not its pixels.
TEST(TrackerPyramid, WithoutLevelZeroTheCoarserLevelsAreTheSame) {
  InputFrame f = flat_frame(160, 120, 0.6f, 0.3f);
  for (size_t p = 0; p < f.depth.size(); ++p) f.depth[p] = 0.6f + 0.001f * static_cast<float>(p % 23);
  f.landmarks = {{30, {80.f, 60.f}, 1.f}, {8, {82.f, 100.f}, 0.5f}};
  f.timestamp_s = 2.5;
  const auto full = BuildPyramid(f, PyramidOptions{}, 2);
  const auto coarse = BuildPyramid(f, PyramidOptions{}, 2, /*keep_level0=*/false);
  ASSERT_EQ(coarse.size(), full.size());
  EXPECT_TRUE(coarse[0].color.empty());
  EXPECT_TRUE(coarse[0].depth.empty());
  EXPECT_EQ(coarse[0].width(), 160);
  EXPECT_EQ(coarse[0].landmarks.size(), 2u);
  EXPECT_EQ(coarse[0].timestamp_s, 2.5);
  for (size_t l = 1; l < full.size(); ++l) {
    EXPECT_EQ(coarse[l].color, full[l].color) << "level " << l;
    EXPECT_EQ(coarse[l].depth, full[l].depth) << "level " << l;
    EXPECT_EQ(coarse[l].width(), full[l].width()) << "level " << l;
    ASSERT_EQ(coarse[l].landmarks.size(), full[l].landmarks.size());
    EXPECT_EQ(coarse[l].landmarks[1].position, full[l].landmarks[1].position) << "level " << l;
  }
  EXPECT_THROW(BuildPyramid(flat_frame(2, 2, 0.5f, 0.5f), PyramidOptions{4}, 1, false), Error);
}

TEST(TrackerPyramid, RejectsBadFramesWithClearErrors) {
  InputFrame f = flat_frame(16, 16, 0.5f, 0.5f);
  InputFrame bad = f;
  bad.color.pop_back();
  std::string why;
  EXPECT_FALSE(bad.IsValid(&why));
  EXPECT_NE(why.find("colour"), std::string::npos);
  EXPECT_THROW(BuildPyramid(bad, PyramidOptions{}), Error);
  bad = f;
  bad.color[7] = std::nanf("");
  EXPECT_THROW(BuildPyramid(bad, PyramidOptions{}), Error);
  bad = f;
  bad.depth.resize(3);
  EXPECT_THROW(BuildPyramid(bad, PyramidOptions{}), Error);
  bad = f;
  bad.landmarks.push_back({80, Eigen::Vector2f(1, 1), 1.f});
  EXPECT_THROW(BuildPyramid(bad, PyramidOptions{}), Error);
  bad = f;
  bad.landmarks.push_back({3, Eigen::Vector2f(1, 1), -1.f});
  EXPECT_THROW(BuildPyramid(bad, PyramidOptions{}), Error);
  EXPECT_THROW(BuildPyramid(flat_frame(2, 2, 0.5f, 0.5f), PyramidOptions{4}), Error);
  PyramidOptions zero;
  zero.levels = 0;
  EXPECT_THROW(BuildPyramid(f, zero), Error);
  // Colour-only frames are fine.
  InputFrame colour_only = f;
  colour_only.depth.clear();
  EXPECT_EQ(BuildPyramid(colour_only, PyramidOptions{}).back().depth.size(), 0u);
}

TEST(TrackerInput, SrgbConversionIsLinear) {
  InputFrame f;
  f.camera = test_camera(2, 1);
  const uint8_t rgb[6] = {0, 255, 188, 10, 128, 64};
  f.SetColorFromSrgb8(rgb, 6);
  EXPECT_FLOAT_EQ(f.color[0], 0.f);
  EXPECT_NEAR(f.color[1], 1.f, 1e-6f);
  EXPECT_NEAR(f.color[2], 0.5029f, 1e-3f);
  EXPECT_NEAR(f.color[4], 0.2158f, 1e-3f);
  EXPECT_THROW(f.SetColorFromSrgb8(rgb, 5), Error);
}

TEST(TrackerInput, InputNormalFacesTheCamera) {
  InputFrame f = flat_frame(9, 9, 0.8f, 0.5f);
  Eigen::Vector3d n;
  ASSERT_TRUE(InputNormal(f, 4, 4, 0.02f, &n));
  EXPECT_NEAR(n.z(), -1.0, 1e-9);
  EXPECT_FALSE(InputNormal(f, 0, 4, 0.02f, &n));  // border
  f.depth[4 * 9 + 5] = 1.2f;
  EXPECT_FALSE(InputNormal(f, 4, 4, 0.02f, &n));  // depth jump
}

TEST(TrackerEnergy, OptionsValidation) {
  EnergyOptions o;
  std::string why;
  EXPECT_TRUE(o.IsValid(&why)) << why;
  o.w_col = -1;
  EXPECT_FALSE(o.IsValid(&why));
  o = EnergyOptions{};
  o.geometry_unit_m = 0;
  EXPECT_FALSE(o.IsValid(&why));
  o = EnergyOptions{};
  o.w_expression_sparsity = -0.1;
  EXPECT_FALSE(o.IsValid(&why));
  o = EnergyOptions{};
  o.expression_sparsity_epsilon = 0;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("epsilon"), std::string::npos);
  for (int sampling : {0, 3, 8}) {
    o = EnergyOptions{};
    o.pixel_sampling = sampling;
    EXPECT_FALSE(o.IsValid(&why)) << sampling;
    EXPECT_NE(why.find("pixel_sampling"), std::string::npos);
  }
  o = EnergyOptions{};
  o.use_point = o.use_plane = o.use_color = o.use_landmarks = o.use_regularizer = false;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("off"), std::string::npos);
}

// A linearisation of `model` at a point near `truth` against a frame rendered at `truth`.
struct Linearised {
  Linearization lin;
  Eigen::VectorXd x;
};

Linearised linearised(const TrackerModel& model, const ParameterLayout& layout, const EnergyOptions& eo,
                 const gpu::PinholeCamera& cam, float distance, uint32_t seed) {
  const CpuSolver solver(model);
  const gpu::FaceParameters truth = true_parameters(model, distance, seed);
  const InputFrame frame = RenderSyntheticFrame(solver.renderer(), model, truth, cam);
  gpu::FaceParameters at = truth;
  std::mt19937 rng(seed + 1);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  at.euler += 0.02f * Eigen::Vector3f(u(rng), u(rng), u(rng));
  at.translation += 0.003f * Eigen::Vector3f(u(rng), u(rng), u(rng));
  for (int k = 0; k < at.delta.size(); ++k) at.delta[k] = std::clamp(at.delta[k] + 0.1f * u(rng), 0.f, 1.f);
  for (auto& g : at.gamma) g += 0.05f * u(rng);
  for (int k = 0; k < at.alpha.size(); ++k) at.alpha[k] += 0.3f * u(rng) * model.identity_sigma[k];
  for (int k = 0; k < at.beta.size(); ++k) at.beta[k] += 0.3f * u(rng) * model.albedo_sigma[k];
  Linearised s;
  s.lin = solver.LinearizeAt(frame, layout, eo, at);
  s.x = layout.Pack(at);
  return s;
}

void expect_every_term_present(const Linearization& lin) {
  for (int t = 0; t < kNumTerms; ++t) {
    EXPECT_GT(lin.term_rows[t + 1] - lin.term_rows[t], 0) << "term " << term_name(static_cast<Term>(t)) << " has no rows";
  }
}

TEST(TrackerGradientCheck, SphereJacobianMatchesFiniteDifferences) {
  const TrackerModel model = sphere_model();
  const ParameterLayout layout = ParameterLayout::Calibration(6, 4, 5);
  for (uint32_t seed : {11u, 12u, 13u}) {
    const Linearised s = linearised(model, layout, EnergyOptions{}, test_camera(160, 120), 0.5f, seed);
    expect_every_term_present(s.lin);
    const GradientCheckResult r = CheckEnergyJacobian(model, s.lin, EnergyOptions{}, s.x, GradientCheckOptions{});
    EXPECT_TRUE(r.ok) << r.report;
    for (int t = 0; t < kNumTerms; ++t) {
      for (int b = 0; b < kNumBlocks; ++b) EXPECT_LE(r.worst_error[t][b], 1e-4) << r.report;
    }
  }
}

TEST(TrackerGradientCheck, FaceModelJacobianMatchesFiniteDifferences) {
  const TrackerModel* model = real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL); the sphere test covers the math";
  const ParameterLayout layout = ParameterLayout::Calibration(model->num_identity(), model->num_albedo(), model->num_expression());
  // 160x120 keeps the pixel count (and the 2 x 175 evaluations) small.
  const Linearised s = linearised(*model, layout, EnergyOptions{}, test_camera(160, 120), 0.5f, 21);
  expect_every_term_present(s.lin);
  const GradientCheckResult r = CheckEnergyJacobian(*model, s.lin, EnergyOptions{}, s.x, GradientCheckOptions{});
  EXPECT_TRUE(r.ok) << r.report;
  std::cout << r.report;
}

TEST(TrackerGradientCheck, CatchesAWrongDerivative) {
  const TrackerModel model = sphere_model();
  const ParameterLayout layout = ParameterLayout::Calibration(6, 4, 5);
  const EnergyOptions eo;
  const Linearised s = linearised(model, layout, eo, test_camera(160, 120), 0.5f, 5);
  Eigen::VectorXd r;
  JacobianMatrix j;
  EvaluateResiduals(model, s.lin, eo, s.x, &r, &j);
  auto f = [&](const Eigen::VectorXd& at, Eigen::VectorXd* out) { EvaluateResiduals(model, s.lin, eo, at, out, nullptr); };
  const GradientCheckOptions opts;
  ASSERT_TRUE(CompareWithFiniteDifferences(f, s.x, j, layout, s.lin.term_rows, opts).ok);

  // The colour rows' columns of `block` zeroed: the check fails there, and only there.
  const Eigen::Index c0 = s.lin.term_rows[static_cast<int>(Term::kColor)];
  const Eigen::Index c1 = s.lin.term_rows[static_cast<int>(Term::kColor) + 1];
  auto only_colour_columns_fail = [&](Block block) {
    JacobianMatrix wrong = j;
    wrong.block(c0, layout.offset(block), c1 - c0, 3).setZero();
    const GradientCheckResult res = CompareWithFiniteDifferences(f, s.x, wrong, layout, s.lin.term_rows, opts);
    EXPECT_FALSE(res.ok);
    for (int t = 0; t < kNumTerms; ++t) {
      for (int b = 0; b < kNumBlocks; ++b) {
        if (t == static_cast<int>(Term::kColor) && b == static_cast<int>(block)) {
          EXPECT_GT(res.worst_error[t][b], 0.5) << res.report;
        } else {
          EXPECT_LE(res.worst_error[t][b], opts.tolerance) << res.report;
        }
      }
    }
  };
  // 1. The shading derivative forgotten: colour residuals treated as independent of rotation
  //    (a classic mistake).
  only_colour_columns_fail(Block::kRotation);
  // 2. The colour's derivative through the projection forgotten (EnergyOptions::
  //    color_follows_projection): colour rows treated as independent of the translation, which
  //    they reach only through where the surface point projects.
  only_colour_columns_fail(Block::kTranslation);
  // 3. A subtle one: one expression column of the point term off by 1%.
  JacobianMatrix wrong = j;
  const int exp0 = layout.offset(Block::kExpression) + 2;
  wrong.col(exp0).segment(0, s.lin.term_rows[1]) *= 1.01;
  const GradientCheckResult res = CompareWithFiniteDifferences(f, s.x, wrong, layout, s.lin.term_rows, opts);
  EXPECT_FALSE(res.ok);
  EXPECT_NEAR(res.worst_error[static_cast<int>(Term::kPoint)][static_cast<int>(Block::kExpression)], 0.01, 2e-3)
      << res.report;
}

// The test sphere rendered at its true parameters (seed 4, 0.5 m, 160x120), tracking layout.
struct SphereScene {
  TrackerModel model = sphere_model();
  CpuSolver solver{model};
  gpu::FaceParameters truth = true_parameters(model, 0.5f, 4);
  InputFrame frame = RenderSyntheticFrame(solver.renderer(), model, truth, test_camera(160, 120));
  ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
};

TEST(TrackerEnergy, DataTermsVanishAtTheTruthAndGrowAwayFromIt) {
  const SphereScene s;
  const EnergyOptions eo;
  const TermEnergies at_truth = s.solver.Energy(s.frame, s.layout, eo, s.truth);
  EXPECT_LT(at_truth[Term::kPoint], 1e-8);
  EXPECT_LT(at_truth[Term::kPlane], 2e-2);  // input normals are finite differences of the depth
  EXPECT_LT(at_truth[Term::kColor], 1e-8);
  EXPECT_LT(at_truth[Term::kLandmark], 1e-8);
  gpu::FaceParameters off = s.truth;
  off.translation.x() += 0.01f;
  off.gamma[0] += 0.5f;
  const TermEnergies away = s.solver.Energy(s.frame, s.layout, eo, off);
  EXPECT_GT(away[Term::kPoint], 100 * std::max(at_truth[Term::kPoint], 1e-8));
  EXPECT_GT(away[Term::kColor], 100 * std::max(at_truth[Term::kColor], 1e-8));
  EXPECT_GT(away[Term::kLandmark], 100 * std::max(at_truth[Term::kLandmark], 1e-8));
  // E_reg is exactly Eq. 11 for the expression block.
  double reg = 0;
  for (int k = 0; k < s.truth.delta.size(); ++k) reg += s.truth.delta[k] * s.truth.delta[k];
  EXPECT_NEAR(at_truth[Term::kRegularizer], eo.w_reg_expression * reg, 1e-6);
}

// EnergyOptions::pixel_sampling 2 and 4: the dense terms on the checkerboard ((i + j) even) or on
// the lattice ((i + 2j) divisible by 4) of the pixels every pixel's linearisation takes, about a
// half or a quarter of them, each term normalised by its own count, so its energy off the truth
// stays that of every pixel within 10 % (the face's residuals change smoothly from pixel to
// pixel); the landmarks and the prior are untouched.
TEST(TrackerEnergy, SampledPixelsAreALatticeOfEveryPixelAtTheSameEnergy) {
  const SphereScene s;
  const EnergyOptions every;
  gpu::FaceParameters off = s.truth;
  off.translation += Eigen::Vector3f(0.004f, -0.002f, 0.003f);
  off.gamma[0] += 0.2f;
  const Linearization all = s.solver.LinearizeAt(s.frame, s.layout, every, off);
  const TermEnergies e_all = s.solver.Energy(s.frame, s.layout, every, off);
  ASSERT_GT(all.num_color, 1000);
  for (const int sampling : {2, 4}) {
    SCOPED_TRACE(sampling);
    EnergyOptions sparse;
    sparse.pixel_sampling = sampling;
    const auto on_lattice = [sampling](const PixelSample& p) {
      return sampling == 2 ? (p.i + p.j) % 2 == 0 : (p.i + 2 * p.j) % 4 == 0;
    };
    const Linearization some = s.solver.LinearizeAt(s.frame, s.layout, sparse, off);
    std::set<std::pair<int, int>> taken;
    size_t lattice = 0;
    for (const PixelSample& p : all.pixels) {
      taken.insert({p.i, p.j});
      lattice += on_lattice(p);
    }
    for (const PixelSample& p : some.pixels) {
      EXPECT_TRUE(on_lattice(p)) << p.i << ", " << p.j;
      EXPECT_TRUE(taken.count({p.i, p.j})) << p.i << ", " << p.j;
    }
    EXPECT_EQ(some.pixels.size(), lattice);
    for (const auto& [n_all, n_some] : {std::pair{all.num_point, some.num_point}, {all.num_plane, some.num_plane},
                                        {all.num_color, some.num_color}}) {
      EXPECT_NEAR(n_some, n_all / static_cast<double>(sampling), 0.02 * n_all);
    }
    EXPECT_EQ(some.landmarks.size(), all.landmarks.size());
    EXPECT_EQ(some.num_regularizer, all.num_regularizer);
    const TermEnergies e_some = s.solver.Energy(s.frame, s.layout, sparse, off);
    for (Term t : {Term::kPoint, Term::kPlane, Term::kColor}) {
      std::cout << term_name(t) << ": every pixel " << e_all[t] << ", 1 in " << sampling << " " << e_some[t] << "\n";
      ASSERT_GT(e_all[t], 0) << term_name(t);
      EXPECT_NEAR(e_some[t], e_all[t], 0.1 * e_all[t]) << term_name(t);  // a half / quarter if a count were left whole
    }
    EXPECT_EQ(e_some[Term::kLandmark], e_all[Term::kLandmark]);
    EXPECT_EQ(e_some[Term::kRegularizer], e_all[Term::kRegularizer]);
  }
}

// The expression rows of E_reg: Eq. 11 with w_reg_expression, plus the reweighted L1 prior whose
// weight is frozen at the linearisation point, so that E_reg there is
// sum w_reg_expression delta^2 + w_sparsity delta^2 / (|delta| + epsilon) (-> w_sparsity |delta|).
TEST(TrackerEnergy, ExpressionPriorRowsAreEq11PlusReweightedL1) {
  const SphereScene s;
  EnergyOptions eo;
  eo.w_reg_expression = 0.3;
  eo.w_expression_sparsity = 0.2;
  eo.expression_sparsity_epsilon = 0.01;
  const Linearization lin = s.solver.LinearizeAt(s.frame, s.layout, eo, s.truth);
  Eigen::VectorXd r;
  JacobianMatrix j;
  TermEnergies e;
  const Eigen::VectorXd x = s.layout.Pack(s.truth);
  EvaluateResiduals(s.model, lin, eo, x, &r, &j, &e);
  double expected = 0, l1 = 0;
  for (int k = 0; k < s.truth.delta.size(); ++k) {
    const double d = s.truth.delta[k];
    expected += eo.w_reg_expression * d * d + eo.w_expression_sparsity * d * d / (std::abs(d) + eo.expression_sparsity_epsilon);
    l1 += eo.w_reg_expression * d * d + eo.w_expression_sparsity * std::abs(d);
  }
  ASSERT_GT(l1, 0);
  EXPECT_NEAR(e[Term::kRegularizer], expected, 1e-9);
  EXPECT_NEAR(e[Term::kRegularizer], l1, 0.05 * l1);  // close to the L1 value with a small epsilon
  // Each row is linear in its weight: the Jacobian is the row's scale, the same at any x.
  const Eigen::Index row0 = lin.term_rows[static_cast<int>(Term::kRegularizer)];
  const int o_exp = s.layout.offset(Block::kExpression);
  for (int k = 0; k < s.truth.delta.size(); ++k) {
    const double d = s.truth.delta[k];
    const double scale = std::sqrt(eo.w_reg_expression + eo.w_expression_sparsity / (std::abs(d) + eo.expression_sparsity_epsilon));
    EXPECT_EQ(j(row0 + k, o_exp + k), static_cast<float>(scale));  // J is stored in float, rounded once
    EXPECT_NEAR(r[row0 + k], scale * d, 1e-12);
  }
}

// Robust colour (EnergyOptions::color_robust_threshold): a pixel whose input shows a colour the
// model cannot (a dark patch painted over the cheek: a hand, a shadow) keeps its rows with the
// weight threshold / difference, frozen for the step; every other pixel keeps weight 1, and
// with the threshold 0 every pixel does. At the truth the weighted colour energy of the patch
// is what it would be with its difference capped at the threshold.
TEST(TrackerEnergy, UnmatchableColoursAreDownWeighted) {
  const SphereScene s;
  InputFrame painted = s.frame;
  const int w = painted.width();
  auto in_patch = [&](int i, int j) { return i >= 70 && i < 90 && j >= 50 && j < 70; };
  for (int j = 0; j < painted.height(); ++j) {
    for (int i = 0; i < w; ++i) {
      if (!in_patch(i, j)) continue;
      for (int c = 0; c < 3; ++c) painted.color[3 * (static_cast<size_t>(j) * w + i) + c] *= 0.3f;
    }
  }
  EnergyOptions eo;
  eo.color_robust_threshold = 0.02;
  const Linearization lin = s.solver.LinearizeAt(painted, s.layout, eo, s.truth);
  int patch = 0;
  double expected_energy = 0;
  for (const PixelSample& px : lin.pixels) {
    if (!px.color) continue;
    const Eigen::Vector3d rendered(s.frame.color[3 * (static_cast<size_t>(px.j) * w + px.i)],
                                   s.frame.color[3 * (static_cast<size_t>(px.j) * w + px.i) + 1],
                                   s.frame.color[3 * (static_cast<size_t>(px.j) * w + px.i) + 2]);
    const double difference = (rendered - px.input_color).norm();
    if (in_patch(px.i, px.j)) {
      ++patch;
      ASSERT_GT(difference, 0.05);
      EXPECT_NEAR(px.color_weight, 0.02 / difference, 1e-5 / difference);
      expected_energy += 0.02 * difference;  // weight * difference^2
    } else {
      EXPECT_EQ(px.color_weight, 1.0);
    }
  }
  ASSERT_GT(patch, 100);
  Eigen::VectorXd r;
  TermEnergies e;
  EvaluateResiduals(s.model, lin, eo, s.layout.Pack(s.truth), &r, nullptr, &e);
  EXPECT_NEAR(e[Term::kColor], eo.w_col * expected_energy / lin.num_color, 1e-3 * e[Term::kColor]);
  eo.color_robust_threshold = 0;
  for (const PixelSample& px : s.solver.LinearizeAt(painted, s.layout, eo, s.truth).pixels) EXPECT_EQ(px.color_weight, 1.0);
  EXPECT_FALSE([] {
    EnergyOptions bad;
    bad.color_robust_threshold = -1;
    return bad.IsValid(nullptr);
  }());
}

// EnergyOptions::color_parts: by default no colour rows on the scalp, ears or neck (hair,
// collars, shadow: colour the albedo model paints as skin), while the geometric terms keep them.
TEST(TrackerEnergy, ColourCoversTheFaceNotTheScalpEarsOrNeck) {
  const TrackerModel* model = real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  gpu::FaceParameters p = true_parameters(*model, 0.5f, 3);
  p.euler.y() += 0.5f;  // turned, so an ear and the side of the head are in view
  const InputFrame frame = RenderSyntheticFrame(solver.renderer(), *model, p, test_camera(320, 240));
  const ParameterLayout layout = ParameterLayout::Tracking(model->num_expression());
  auto in_parts = [&](const PixelSample& px, gpu::PartMask parts) {
    for (int k = 0; k < 3; ++k) {
      if (!((parts >> model->render.vertex_part[px.vertex[k]]) & 1u)) return false;
    }
    return true;
  };
  const gpu::PartMask excluded = gpu::kAllParts & ~kColorParts;
  EnergyOptions eo;
  int colour = 0, geometry_outside = 0;
  for (const PixelSample& px : solver.LinearizeAt(frame, layout, eo, p).pixels) {
    EXPECT_FALSE(px.color && !in_parts(px, kColorParts)) << "colour at pixel " << px.i << "," << px.j;
    colour += px.color;
    geometry_outside += (px.point || px.plane) && in_parts(px, excluded);
  }
  EXPECT_GT(colour, 1000);
  EXPECT_GT(geometry_outside, 100);
  eo.color_parts = gpu::kAllParts;
  int colour_outside = 0;
  for (const PixelSample& px : solver.LinearizeAt(frame, layout, eo, p).pixels) colour_outside += px.color && in_parts(px, excluded);
  EXPECT_GT(colour_outside, 100);
  eo.color_parts = 0;
  EXPECT_FALSE(eo.IsValid(nullptr));
}

// The pixel rows split over threads: r, J and the energies are bit-identical to one thread
// (each pixel writes only its own rows), for thread counts that do and do not divide the pixels.
// J is not zeroed as a whole (energy.cc writes every row it owns): a buffer that held anything
// before, NaN here, must come out exactly as a fresh one, for every term and thread count.
TEST(TrackerEnergy, EveryEntryOfJIsWrittenWhateverTheBufferHeld) {
  const TrackerModel model = sphere_model();
  const ParameterLayout layout = ParameterLayout::Calibration(6, 4, 5);
  const Linearised s = linearised(model, layout, EnergyOptions{}, test_camera(320, 240), 0.5f, 17);
  for (int t = 0; t < kNumTerms; ++t) ASSERT_GT(s.lin.term_rows[t + 1], s.lin.term_rows[t]) << term_name(Term(t));
  JacobianMatrix fresh;
  EvaluateResiduals(model, s.lin, EnergyOptions{}, s.x, nullptr, &fresh, nullptr, 1);
  for (int threads : {1, 2}) {
    JacobianMatrix reused = JacobianMatrix::Constant(fresh.rows(), fresh.cols(), std::nan(""));
    EvaluateResiduals(model, s.lin, EnergyOptions{}, s.x, nullptr, &reused, nullptr, threads);
    ASSERT_TRUE(reused.allFinite()) << threads << " threads";
    EXPECT_TRUE((reused.array() == fresh.array()).all()) << threads << " threads";
  }
}

TEST(TrackerEnergy, ThreadedEvaluationIsBitIdentical) {
  const TrackerModel* real = real_model();
  const TrackerModel model = real ? *real : sphere_model();
  const ParameterLayout layout = real ? ParameterLayout::Calibration(20, 5, model.num_expression())
                                      : ParameterLayout::Calibration(6, 4, 5);
  const Linearised s = linearised(model, layout, EnergyOptions{}, test_camera(640, 480), 0.5f, 31);
  ASSERT_GT(s.lin.pixels.size(), 4u * 1024u) << "too few pixels to split into threads";
  Eigen::VectorXd r1;
  JacobianMatrix j1;
  TermEnergies e1;
  EvaluateResiduals(model, s.lin, EnergyOptions{}, s.x, &r1, &j1, &e1, 1);
  for (int threads : {2, 3, 4}) {
    Eigen::VectorXd r;
    JacobianMatrix j;
    TermEnergies e;
    EvaluateResiduals(model, s.lin, EnergyOptions{}, s.x, &r, &j, &e, threads);
    ASSERT_EQ(r.size(), r1.size());
    EXPECT_TRUE((r.array() == r1.array()).all()) << threads << " threads";
    EXPECT_TRUE((j.array() == j1.array()).all()) << threads << " threads";
    for (int t = 0; t < kNumTerms; ++t) EXPECT_EQ(e.value[t], e1.value[t]) << threads << " threads";
    Eigen::VectorXd r_only;
    EvaluateResiduals(model, s.lin, EnergyOptions{}, s.x, &r_only, nullptr, nullptr, threads);
    EXPECT_TRUE((r_only.array() == r1.array()).all()) << threads << " threads, residuals only";
  }
}

TEST(TrackerEnergy, LinearizeRejectsMismatchedInputs) {
  const TrackerModel model = sphere_model();
  const CpuSolver solver(model);
  const gpu::FaceParameters p = true_parameters(model, 0.5f, 4);
  const InputFrame frame = RenderSyntheticFrame(solver.renderer(), model, p, test_camera(160, 120));
  const gpu::VertexState st = solver.renderer().evaluate(p);
  const gpu::GBuffer other = solver.renderer().rasterize(st, test_camera(80, 60), {});
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  EXPECT_THROW(Linearize(model, layout, p, st, other, frame, EnergyOptions{}), Error);
  EXPECT_THROW(Linearize(model, ParameterLayout::Tracking(99), p, st, solver.renderer().rasterize(st, frame.camera, {}),
                         frame, EnergyOptions{}),
               Error);
  const Linearization lin = solver.LinearizeAt(frame, layout, EnergyOptions{}, p);
  Eigen::VectorXd r;
  EXPECT_THROW(EvaluateResiduals(model, lin, EnergyOptions{}, Eigen::VectorXd::Zero(3), &r, nullptr), Error);
  // A model whose expression was never indexed (RenderModel::IndexExpression) is refused, not read
  // past its index.
  TrackerModel unindexed = model;
  unindexed.render.expression_columns = {};
  EXPECT_THROW(EvaluateResiduals(unindexed, lin, EnergyOptions{}, layout.Pack(p), &r, nullptr), Error);
}

TEST(TrackerEnergy, InvisibleLandmarksArePruned) {
  const SphereScene s;
  gpu::FaceParameters p = s.truth;
  EXPECT_EQ(s.solver.LinearizeAt(s.frame, s.layout, EnergyOptions{}, p).landmarks.size(), s.model.landmarks.size());
  p.euler.y() += static_cast<float>(M_PI);  // the landmark side is now behind the sphere
  EXPECT_EQ(s.solver.LinearizeAt(s.frame, s.layout, EnergyOptions{}, p).landmarks.size(), 0u);
}

// EnergyOptions::landmark_occlusion_m: a landmark's vertex is kept unless the render shows a
// surface more than 1 cm in front of it at its pixel.
TEST(TrackerEnergy, LandmarkVisibilityIsADepthTestAgainstTheRender) {
  gpu::GBuffer g;
  g.Resize(4, 4);
  gpu::PinholeCamera cam;
  cam.width = cam.height = 4;
  cam.fx = cam.fy = 2;
  cam.cx = cam.cy = 1.5f;
  const Eigen::Vector3f x(0.25f, -0.25f, 1.0f);  // projects to (2.0, 1.0): pixel (2, 1)
  const size_t p = 1 * 4 + 2;
  EXPECT_TRUE(LandmarkVertexVisible(x, g, cam, 0.01f));  // nothing rendered there: the silhouette
  g.triangle[p] = 0;
  auto at_depth = [&](float z) {
    g.position[3 * p + 2] = z;
    return LandmarkVertexVisible(x, g, cam, 0.01f);
  };
  EXPECT_TRUE(at_depth(1.0f));     // the vertex's own surface
  EXPECT_TRUE(at_depth(0.995f));   // 5 mm nearer: a neighbouring slope at this pixel
  EXPECT_FALSE(at_depth(0.98f));   // 2 cm nearer: something hides it (a nose before an eye)
  EXPECT_TRUE(at_depth(1.2f));     // behind it
  EXPECT_TRUE(LandmarkVertexVisible(Eigen::Vector3f(10, 0, 1), g, cam, 0.01f));  // outside the image
  EXPECT_FALSE(LandmarkVertexVisible(Eigen::Vector3f(0, 0, cam.near_plane * 0.5f), g, cam, 0.01f));
  EnergyOptions o;
  o.landmark_occlusion_m = 0;
  std::string why;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("landmark_occlusion_m"), std::string::npos) << why;
}

// The eye landmarks sit on eyelid-margin vertices whose normals point away from the camera (the
// inner lid's faces outweigh the outer ones): a normal test pruned all 12 of them (and 33), so
// blinks were invisible to the landmark term. The depth test keeps every inner landmark of a
// frontal face (the eyes and 33 when asked: EnergyOptions::all_inner_landmarks), and still drops the far
// side of a face turned 70 degrees.
TEST(TrackerEnergy, EveryInnerLandmarkOfAFrontalFaceCounts) {
  const TrackerModel* real = real_model();
  if (!real) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*real);
  gpu::FaceParameters truth = true_parameters(*real, 0.8f, 3);
  const ParameterLayout layout = ParameterLayout::Tracking(real->num_expression());
  const InputFrame frame = RenderSyntheticFrame(solver.renderer(), *real, truth, test_camera(640, 480));
  size_t inner = 0, eyes = 0;
  for (const auto& l : real->landmarks) inner += (l.flags & kLandmarkInner) != 0;
  EnergyOptions with_eyes;
  with_eyes.all_inner_landmarks = true;
  // The eyes and 33 are off by default, but for the four eye corners on frames without depth.
  ASSERT_TRUE(frame.has_depth());
  EXPECT_EQ(solver.LinearizeAt(frame, layout, EnergyOptions{}, truth).landmarks.size(), inner - 13);
  InputFrame colour_only = frame;
  colour_only.depth.clear();
  EXPECT_EQ(solver.LinearizeAt(colour_only, layout, EnergyOptions{}, truth).landmarks.size(), inner - 9);
  EnergyOptions without_corners;
  without_corners.eye_corner_landmarks = false;
  EXPECT_EQ(solver.LinearizeAt(colour_only, layout, without_corners, truth).landmarks.size(), inner - 13);
  const Linearization lin = solver.LinearizeAt(frame, layout, with_eyes, truth);
  for (const auto& s : lin.landmarks)
    for (const auto& l : real->landmarks)
      if (l.vertex == s.vertex && l.ibug_index >= 36 && l.ibug_index <= 47) ++eyes;
  EXPECT_EQ(lin.landmarks.size(), inner);
  EXPECT_EQ(eyes, 12u);
  gpu::FaceParameters turned = truth;
  turned.euler.y() += static_cast<float>(70 * M_PI / 180);
  const InputFrame side = RenderSyntheticFrame(solver.renderer(), *real, turned, test_camera(640, 480));
  const size_t kept = solver.LinearizeAt(side, layout, with_eyes, turned).landmarks.size();
  EXPECT_LT(kept, inner);
  EXPECT_GT(kept, inner / 3);
}

// Tracking's precomputed identity shapes and albedos (Linearization::fixed) change nothing but
// the time: r and J are bit-identical with and without them, on one and two threads (and with
// parts made on several threads). Parts made
// for another identity or albedo are not used; a layout that solves a block uses them only where
// x's coefficients are those they were made for.
TEST(TrackerEnergy, FixedModelPartsGiveTheSameBits) {
  const TrackerModel* real = real_model();
  const TrackerModel model = real ? *real : sphere_model();
  for (const ParameterLayout& layout :
       {ParameterLayout::Tracking(model.num_expression()), ParameterLayout::Calibration(4, 3, model.num_expression())}) {
    const Linearised s = linearised(model, layout, EnergyOptions{}, test_camera(320, 240), 0.5f, 23);
    for (int t = 0; t < kNumTerms; ++t) ASSERT_GT(s.lin.term_rows[t + 1], s.lin.term_rows[t]) << term_name(Term(t));
    Eigen::VectorXd r0;
    JacobianMatrix j0;
    EvaluateResiduals(model, s.lin, EnergyOptions{}, s.x, &r0, &j0, nullptr, 1);

    gpu::FaceParameters other = s.lin.base;
    other.alpha[0] += 0.5f * model.identity_sigma[0];
    other.beta[0] += 0.5f * model.albedo_sigma[0];
    for (const gpu::FaceParameters& made_for : {s.lin.base, other}) {
      Linearization with = s.lin;
      // Made on three threads: the parts (and so r and J) do not depend on the count.
      with.fixed = std::make_shared<const FixedModelParts>(ComputeFixedModelParts(model, made_for, 3));
      for (int threads : {1, 2}) {
        Eigen::VectorXd r;
        JacobianMatrix j;
        EvaluateResiduals(model, with, EnergyOptions{}, s.x, &r, &j, nullptr, threads);
        EXPECT_TRUE((r.array() == r0.array()).all()) << layout.num_identity << " identity unknowns, " << threads << " threads";
        EXPECT_TRUE((j.array() == j0.array()).all()) << layout.num_identity << " identity unknowns, " << threads << " threads";
      }
    }
  }
}

// A calibration's frames share one set of parts made for the step's own identity and albedo
// (FixedModelPartsAt, which the CPU solver makes once per step for all frames): r and J
// are the same bits as each evaluation computing them vertex by vertex, at the linearisation
// point and away from it (a trial step).
TEST(TrackerEnergy, PartsMadeAtXServeALayoutThatSolvesTheIdentity) {
  const TrackerModel* real = real_model();
  const TrackerModel model = real ? *real : sphere_model();
  const ParameterLayout layout = ParameterLayout::Calibration(4, 3, model.num_expression());
  const Linearised s = linearised(model, layout, EnergyOptions{}, test_camera(320, 240), 0.5f, 29);
  Eigen::VectorXd away = s.x;
  for (int k = 0; k < layout.num_identity; ++k) away[layout.offset(Block::kIdentity) + k] += 0.3 * (k + 1);
  for (int k = 0; k < layout.num_albedo; ++k) away[layout.offset(Block::kAlbedo) + k] -= 0.2 * (k + 1);
  for (const Eigen::VectorXd* at : {&s.x, static_cast<const Eigen::VectorXd*>(&away)}) {
    const Eigen::VectorXd& x = *at;
    const Eigen::VectorXd& other = at == &away ? s.x : away;
    Eigen::VectorXd r0;
    JacobianMatrix j0;
    EvaluateResiduals(model, s.lin, EnergyOptions{}, x, &r0, &j0, nullptr, 1);
    Linearization with = s.lin;
    with.fixed = FixedModelPartsAt(model, s.lin, x, nullptr, 2);
    ASSERT_EQ(with.fixed->alpha.size(), model.num_identity());
    EXPECT_EQ(with.fixed->alpha[0], x[layout.offset(Block::kIdentity)]);  // x's identity, not the base's
    // Kept where they were made for x (a step linearised at its accepted trial x), not elsewhere.
    EXPECT_EQ(FixedModelPartsAt(model, s.lin, x, with.fixed).get(), with.fixed.get());
    EXPECT_NE(FixedModelPartsAt(model, s.lin, other, with.fixed).get(), with.fixed.get());
    for (int threads : {1, 2}) {
      Eigen::VectorXd r;
      JacobianMatrix j;
      EvaluateResiduals(model, with, EnergyOptions{}, x, &r, &j, nullptr, threads);
      EXPECT_TRUE((r.array() == r0.array()).all()) << threads << " threads";
      EXPECT_TRUE((j.array() == j0.array()).all()) << threads << " threads";
    }
    if (at == &away) {
      // Parts made at the linearisation point do not serve another identity: the same bits too.
      Linearization stale = s.lin;
      stale.fixed = FixedModelPartsAt(model, s.lin, s.x);
      Eigen::VectorXd r;
      EvaluateResiduals(model, stale, EnergyOptions{}, x, &r, nullptr, nullptr, 1);
      EXPECT_TRUE((r.array() == r0.array()).all());
    }
  }
}

}  // namespace
}  // namespace face_reenact::tracker
