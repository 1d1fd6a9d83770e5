// The PCG inner solve on its own: both operators agree, it converges to the direct solution,
// and degenerate systems neither crash nor produce NaN.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <random>

#include "face_reenact/tracker/pcg.h"

namespace face_reenact::tracker {
namespace {

JacobianMatrix random_jacobian(int rows, int cols, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g;
  JacobianMatrix j(rows, cols);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) j(r, c) = g(rng) * (1.0 + c);  // badly scaled columns
  }
  return j;
}

TEST(TrackerPcg, OperatorsAgree) {
  const JacobianMatrix j = random_jacobian(300, 40, 1);
  const MatrixFreeNormalOperator mf(j, 0.01);
  const AssembledNormalOperator as(j, 0.01);
  const Eigen::VectorXd x = Eigen::VectorXd::LinSpaced(40, -1, 1);
  Eigen::VectorXd a(40), b(40);
  mf.Apply(x, &a);
  as.Apply(x, &b);
  EXPECT_LT((a - b).norm(), 1e-9 * b.norm());
  EXPECT_LT((mf.Diagonal() - as.Diagonal()).norm(), 1e-9 * as.Diagonal().norm());
  const Eigen::MatrixXd expect = j.transpose() * j;
  Eigen::VectorXd direct = expect * x;
  direct.array() += 0.01 * expect.diagonal().array() * x.array();
  EXPECT_LT((direct - b).norm(), 1e-9 * b.norm());
}

TEST(TrackerPcg, ConvergesToTheDirectSolution) {
  const JacobianMatrix j = random_jacobian(500, 60, 2);
  const AssembledNormalOperator a(j, 0.0);
  const Eigen::VectorXd b = Eigen::VectorXd::LinSpaced(60, 1, 2);
  const Eigen::VectorXd direct = a.matrix().ldlt().solve(b);
  PcgScratch scratch;
  scratch.Resize(60);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(60);
  const PcgSummary s = Pcg(a, b, PcgOptions{200, 1e-12}, &scratch, &x);
  EXPECT_TRUE(s.converged);
  EXPECT_LT((x - direct).norm(), 1e-8 * direct.norm());
  // A few iterations (the tracker's 4) already lower the residual, and Jacobi helps on these
  // badly scaled columns.
  Eigen::VectorXd x4 = Eigen::VectorXd::Zero(60);
  const PcgSummary s4 = Pcg(a, b, PcgOptions{4, 0}, &scratch, &x4);
  EXPECT_EQ(s4.iterations, 4);
  EXPECT_LT(s4.final_residual_norm, 0.5 * s4.initial_residual_norm);
}

TEST(TrackerPcg, DegenerateSystemsStayFinite) {
  JacobianMatrix j = random_jacobian(50, 10, 3);
  j.col(4).setZero();  // a parameter nothing depends on
  const MatrixFreeNormalOperator a(j, 0.0);
  PcgScratch scratch;
  scratch.Resize(10);
  Eigen::VectorXd b = Eigen::VectorXd::Ones(10);
  b[4] = 0;
  Eigen::VectorXd x = Eigen::VectorXd::Zero(10);
  Pcg(a, b, PcgOptions{20, 1e-12}, &scratch, &x);
  EXPECT_TRUE(x.allFinite());
  EXPECT_EQ(x[4], 0.0);
  // Zero right-hand side: nothing to do.
  Eigen::VectorXd z = Eigen::VectorXd::Zero(10);
  const PcgSummary s = Pcg(a, Eigen::VectorXd::Zero(10), PcgOptions{}, &scratch, &z);
  EXPECT_TRUE(s.converged);
  EXPECT_EQ(s.iterations, 0);
  EXPECT_EQ(z.norm(), 0.0);
  std::string why;
  EXPECT_FALSE((PcgOptions{0, 1e-6}).IsValid(&why));
}

}  // namespace
}  // namespace face_reenact::tracker
