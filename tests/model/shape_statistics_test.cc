#include "face_reenact/model/shape_statistics.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <random>

#include "face_reenact/common/error.h"

namespace face_reenact {
namespace {

Eigen::VectorXf random_points(int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> g;
  Eigen::VectorXf p(3 * n);
  for (int i = 0; i < p.size(); ++i) p[i] = g(rng);
  return p;
}

TEST(FitRigid, RecoversAKnownRotationAndTranslation) {
  Eigen::VectorXf x = random_points(50, 1);
  RigidTransform truth;
  truth.rotation = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  truth.translation = Eigen::Vector3d(0.3, -2, 5);
  Eigen::VectorXf y = x;
  apply_rigid(truth, y);
  RigidTransform t = fit_rigid(x, y);
  EXPECT_LT((t.rotation - truth.rotation).norm(), 1e-5);
  EXPECT_LT((t.translation - truth.translation).norm(), 1e-4);
  Eigen::VectorXf z = x;
  apply_rigid(t, z);
  EXPECT_LT((z - y).cwiseAbs().maxCoeff(), 1e-4f);
}

TEST(FitRigid, NeverReflectsAndHonoursWeights) {
  Eigen::VectorXf x = random_points(30, 2);
  Eigen::VectorXf y = x;
  for (int i = 0; i < 30; ++i) y[3 * i] = -y[3 * i];  // a mirror image: no rotation reaches it
  RigidTransform t = fit_rigid(x, y);
  EXPECT_NEAR(t.rotation.determinant(), 1.0, 1e-9);
  // Zero weight on outliers: the fit follows the weighted points only.
  Eigen::VectorXf a = random_points(20, 3), b = a;
  for (int i = 0; i < 5; ++i) b.segment<3>(3 * i) += Eigen::Vector3f(10, -7, 3);
  Eigen::VectorXf w = Eigen::VectorXf::Ones(20);
  w.head(5).setZero();
  RigidTransform tw = fit_rigid(a, b, w);
  EXPECT_LT((tw.rotation - Eigen::Matrix3d::Identity()).norm(), 1e-5);
  EXPECT_LT(tw.translation.norm(), 1e-5);
  EXPECT_THROW(fit_rigid(a, b, Eigen::VectorXf::Zero(20)), Error);
  EXPECT_THROW(fit_rigid(a, b.head(30)), Error);
  EXPECT_THROW(fit_rigid(Eigen::VectorXf(), Eigen::VectorXf()), Error);
}

TEST(AlignSamples, RemovesRigidMotionButKeepsShapeChanges) {
  const int n = 40, s = 12;
  Eigen::VectorXf base = random_points(n, 4);
  Eigen::MatrixXf samples(3 * n, s);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  for (int c = 0; c < s; ++c) {
    RigidTransform t;
    t.rotation = Eigen::AngleAxisd(u(rng), Eigen::Vector3d(u(rng), u(rng), 1).normalized()).toRotationMatrix();
    t.translation = Eigen::Vector3d(u(rng), u(rng), u(rng)) * 10;
    Eigen::VectorXf col = base;
    apply_rigid(t, col);
    samples.col(c) = col;
  }
  ProcrustesSummary sum;
  Eigen::VectorXf mean = align_samples(&samples, Eigen::VectorXf(), 20, 1e-7, &sum);
  EXPECT_LT(sum.mean_residual, 1e-4);
  for (int c = 0; c < s; ++c) EXPECT_LT((samples.col(c) - mean).cwiseAbs().maxCoeff(), 1e-3f);
  // The mean has the base's shape (same pairwise distances).
  EXPECT_NEAR((mean.segment<3>(0) - mean.segment<3>(3)).norm(), (base.segment<3>(0) - base.segment<3>(3)).norm(), 1e-4);
}

TEST(RigidMotionShare, IsOneForRigidFieldsZeroForShapeChangesAndHonoursWeights) {
  const int n = 30;
  const Eigen::VectorXf mean = random_points(n, 6);
  Eigen::Vector3f c = Eigen::Vector3f::Zero();
  for (int i = 0; i < n; ++i) c += mean.segment<3>(3 * i) / n;
  Eigen::VectorXf shift(3 * n), spin(3 * n), scale(3 * n);
  for (int i = 0; i < n; ++i) {
    shift.segment<3>(3 * i) = Eigen::Vector3f(0.2f, -0.5f, 1.f);
    spin.segment<3>(3 * i) = Eigen::Vector3f(0.3f, 1.f, -0.4f).cross(mean.segment<3>(3 * i) - c);
    scale.segment<3>(3 * i) = mean.segment<3>(3 * i) - c;  // orthogonal to every rigid motion
  }
  auto one = [](const Eigen::VectorXf& v) {
    Eigen::MatrixXf b = v.normalized();
    return b;
  };
  const Eigen::VectorXf sd = Eigen::VectorXf::Constant(1, 2.f);
  EXPECT_NEAR(rigid_motion_share(mean, one(shift), sd), 1.0, 1e-6);
  EXPECT_NEAR(rigid_motion_share(mean, one(spin), sd), 1.0, 1e-6);
  EXPECT_NEAR(rigid_motion_share(mean, one(scale), sd), 0.0, 1e-6);
  // Two components, the rigid one with twice the standard deviation: 4 / (4 + 1).
  Eigen::MatrixXf two(3 * n, 2);
  two << one(shift), one(scale);
  EXPECT_NEAR(rigid_motion_share(mean, two, Eigen::Vector2f(2.f, 1.f)), 0.8, 1e-6);
  // A shift of only the unweighted half is not rigid motion of the weighted half: it is no motion
  // of it at all, so nothing is left there but the scale.
  Eigen::VectorXf w = Eigen::VectorXf::Zero(n);
  w.head(n / 2).setOnes();
  Eigen::VectorXf tail_shift = shift;
  tail_shift.head(3 * (n / 2)).setZero();
  Eigen::Vector3f head_centre = Eigen::Vector3f::Zero();
  for (int i = 0; i < n / 2; ++i) head_centre += mean.segment<3>(3 * i) / (n / 2);
  Eigen::VectorXf head_scale(3 * n);  // a scale about the weighted points' own centroid
  for (int i = 0; i < n; ++i) head_scale.segment<3>(3 * i) = mean.segment<3>(3 * i) - head_centre;
  two << one(tail_shift), one(head_scale);
  EXPECT_NEAR(rigid_motion_share(mean, two, Eigen::Vector2f(2.f, 1.f), w), 0.0, 1e-6);
  // Over all points that half shift is at least half translation: 4 * 0.5 / 5 or more.
  EXPECT_GT(rigid_motion_share(mean, two, Eigen::Vector2f(2.f, 1.f)), 0.39);
  EXPECT_THROW(rigid_motion_share(mean, two, Eigen::Vector3f::Ones()), Error);
  EXPECT_THROW(rigid_motion_share(mean, two, Eigen::Vector2f::Ones(), Eigen::VectorXf::Zero(n)), Error);
  EXPECT_THROW(rigid_motion_share(mean.head(10), two, Eigen::Vector2f::Ones()), Error);
}

// Aligning on a subset of the points leaves no rigid motion on that subset, while aligning on
// all points (each sample also deformed elsewhere) leaves a rigid share there: the builder's
// face-region alignment in miniature.
TEST(AlignSamples, WeightedAlignmentLeavesNoRigidShareOnTheWeightedPoints) {
  const int n = 40, s = 60;
  const Eigen::VectorXf base = random_points(n, 7);
  Eigen::VectorXf w = Eigen::VectorXf::Zero(n);
  w.head(n / 2).setOnes();
  std::mt19937 rng(8);
  std::normal_distribution<float> g;
  Eigen::MatrixXf samples(3 * n, s);
  for (int c = 0; c < s; ++c) {
    Eigen::VectorXf col = base;
    for (int i = 0; i < col.size(); ++i) col[i] += (i < 3 * (n / 2) ? 0.02f : 0.3f) * g(rng);
    samples.col(c) = col;
  }
  auto share_after = [&](const Eigen::VectorXf& align_weights) {
    Eigen::MatrixXf a = samples;
    const Eigen::VectorXf mean = align_samples(&a, align_weights, 20, 1e-9, nullptr);
    a.colwise() -= mean;
    PcaOptions po;
    po.min_components = po.max_components = 20;
    po.subspace_size = 20;
    PcaResult pca = pca_of_centered_samples(a, po);
    return rigid_motion_share(mean, pca.basis, pca.sigma, w);
  };
  EXPECT_LT(share_after(w), 1e-4);
  EXPECT_GT(share_after(Eigen::VectorXf()), 0.05);
}

// Samples with a known covariance: orthonormal directions Q with standard deviations sd.
Eigen::MatrixXf known_samples(int dim, int count, const std::vector<double>& sd, uint32_t seed, Eigen::MatrixXd* q) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g;
  Eigen::MatrixXd r(dim, static_cast<int>(sd.size()));
  for (int i = 0; i < r.size(); ++i) r.data()[i] = g(rng);
  *q = Eigen::HouseholderQR<Eigen::MatrixXd>(r).householderQ() * Eigen::MatrixXd::Identity(dim, r.cols());
  Eigen::MatrixXd a(dim, count);
  for (int c = 0; c < count; ++c) {
    Eigen::VectorXd v = Eigen::VectorXd::Zero(dim);
    for (size_t k = 0; k < sd.size(); ++k) v += q->col(static_cast<int>(k)) * sd[k] * g(rng);
    a.col(c) = v;
  }
  a.colwise() -= a.rowwise().mean();
  return a.cast<float>();
}

TEST(Pca, MatchesTheExactEigenDecompositionOnASmallKnownMatrix) {
  // 4 samples in 3-D, hand-checkable: variance only along x (values -3,-1,1,3: var 20/3) and
  // y (0.5,-0.5,-0.5,0.5: var 1/3, uncorrelated with x).
  Eigen::MatrixXf a(3, 4);
  a << -3, -1, 1, 3,  //
      0.5f, -0.5f, -0.5f, 0.5f,  //
      0, 0, 0, 0;
  PcaOptions o;
  o.min_components = 1;
  o.max_components = 3;
  o.subspace_size = 3;
  PcaResult r = pca_of_centered_samples(a, o);
  ASSERT_EQ(r.sigma.size(), 2);  // the zero-variance z direction is never kept
  EXPECT_NEAR(r.sigma[0], std::sqrt(20.0 / 3), 1e-5);
  EXPECT_NEAR(r.sigma[1], std::sqrt(1.0 / 3), 1e-5);
  EXPECT_NEAR(std::abs(r.basis(0, 0)), 1, 1e-6);
  EXPECT_NEAR(std::abs(r.basis(1, 1)), 1, 1e-6);
  EXPECT_GT(r.basis(0, 0), 0);  // sign convention: largest entry positive
  EXPECT_NEAR(r.explained_variance, 1.0, 1e-9);
  EXPECT_NEAR(r.total_variance, 20.0 / 3 + 1.0 / 3, 1e-5);
  EXPECT_TRUE(r.dense);
}

TEST(Pca, RandomisedPathAgreesWithDensePath) {
  std::vector<double> sd;
  for (int k = 0; k < 30; ++k) sd.push_back(10.0 * std::pow(0.8, k));
  Eigen::MatrixXd q;
  Eigen::MatrixXf a = known_samples(300, 400, sd, 7, &q);
  PcaOptions dense;
  dense.min_components = 10;
  dense.max_components = 20;
  dense.subspace_size = 80;
  PcaOptions randomised = dense;
  randomised.dense_limit = 100;  // 400 samples > 100: subspace iteration
  PcaResult d = pca_of_centered_samples(a, dense), r = pca_of_centered_samples(a, randomised);
  EXPECT_TRUE(d.dense);
  EXPECT_FALSE(r.dense);
  ASSERT_EQ(d.sigma.size(), r.sigma.size());
  for (int k = 0; k < d.sigma.size(); ++k) {
    EXPECT_NEAR(r.sigma[k], d.sigma[k], 1e-3 * d.sigma[0]) << k;
    EXPECT_GT(std::abs(r.basis.col(k).dot(d.basis.col(k))), 0.99f) << k;
  }
  // Recovered directions span the true ones; sigma decreasing; orthonormal columns.
  for (int k = 0; k < 5; ++k) {
    EXPECT_GT((q.leftCols(8).transpose() * d.basis.col(k).cast<double>()).norm(), 0.98) << k;
    EXPECT_NEAR(d.sigma[k], sd[k], 0.15 * sd[k]) << k;
  }
  const Eigen::MatrixXf gram = d.basis.transpose() * d.basis;
  EXPECT_LT((gram - Eigen::MatrixXf::Identity(gram.rows(), gram.cols())).cwiseAbs().maxCoeff(), 1e-5f);
  for (int k = 1; k < d.sigma.size(); ++k) EXPECT_LE(d.sigma[k], d.sigma[k - 1]);
}

TEST(Pca, KeepsComponentsForTheVarianceTargetWithinBounds) {
  std::vector<double> sd(40, 1.0);  // flat spectrum: 99.5% needs ~40 components
  Eigen::MatrixXd q;
  Eigen::MatrixXf a = known_samples(100, 300, sd, 9, &q);
  PcaOptions o;
  o.min_components = 5;
  o.max_components = 20;
  o.subspace_size = 60;
  PcaResult r = pca_of_centered_samples(a, o);
  EXPECT_EQ(r.sigma.size(), 20);  // capped
  EXPECT_GT(r.components_for_target, 20);
  o.max_components = 60;
  o.variance_target = 0.5;
  r = pca_of_centered_samples(a, o);
  EXPECT_EQ(r.sigma.size(), r.components_for_target);
  EXPECT_GE(r.explained_variance, 0.5);
}

TEST(Pca, RejectsDegenerateInput) {
  PcaOptions o;
  EXPECT_THROW(pca_of_centered_samples(Eigen::MatrixXf::Zero(6, 1), o), Error);
  EXPECT_THROW(pca_of_centered_samples(Eigen::MatrixXf::Zero(6, 5), o), Error);
  Eigen::MatrixXf bad = Eigen::MatrixXf::Ones(6, 5);
  bad(0, 0) = std::nanf("");
  EXPECT_THROW(pca_of_centered_samples(bad, o), Error);
  o.max_components = 1;
  o.min_components = 2;
  std::string why;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_THROW(pca_of_centered_samples(Eigen::MatrixXf::Random(6, 5), o), Error);
}

}  // namespace
}  // namespace face_reenact
