// The PCG inner solve on its own: both operators agree, it converges to the direct solution,
// and degenerate systems neither crash nor produce NaN.
#include <cmath>
#include <vector>
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <random>

#include "row_kernels.h"
#include "face_reenact/common/error.h"
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
  const Eigen::MatrixXd jd = j.cast<double>();
  const Eigen::MatrixXd expect = jd.transpose() * jd;
  Eigen::VectorXd direct = expect * x;
  direct.array() += 0.01 * expect.diagonal().array() * x.array();
  EXPECT_LT((direct - b).norm(), 1e-9 * b.norm());
}

// Calibration's joint system: frame blocks over (shared, own) columns behave exactly like the
// dense stacked matrix with zeros outside each frame's columns.
TEST(TrackerPcg, StackedJacobianEqualsTheDenseStack) {
  const int shared = 7, own = 5, frames = 3;
  std::vector<JacobianMatrix> blocks;
  for (int f = 0; f < frames; ++f) blocks.push_back(random_jacobian(40 + 10 * f, shared + own, 10 + f));
  StackedJacobian stacked(shared, own);
  JacobianMatrix dense = JacobianMatrix::Zero(40 + 50 + 60, shared + frames * own);
  Eigen::Index row = 0;
  for (int f = 0; f < frames; ++f) {
    stacked.AddFrame(blocks[f]);
    dense.block(row, 0, blocks[f].rows(), shared) = blocks[f].leftCols(shared);
    dense.block(row, shared + f * own, blocks[f].rows(), own) = blocks[f].rightCols(own);
    row += blocks[f].rows();
  }
  ASSERT_EQ(stacked.rows(), dense.rows());
  ASSERT_EQ(stacked.cols(), dense.cols());
  const Eigen::VectorXd x = Eigen::VectorXd::LinSpaced(dense.cols(), -1, 2);
  const Eigen::VectorXd v = Eigen::VectorXd::LinSpaced(dense.rows(), 3, -1);
  const Eigen::MatrixXd dd = dense.cast<double>();  // the products accumulate in double
  Eigen::VectorXd jx, jtv;
  stacked.Multiply(x, &jx);
  stacked.MultiplyTransposed(v, &jtv);
  EXPECT_LT((jx - dd * x).norm(), 1e-12 * jx.norm());
  EXPECT_LT((jtv - dd.transpose() * v).norm(), 1e-12 * jtv.norm());
  Eigen::VectorXd jtjx;
  stacked.MultiplyNormal(x, &jtjx);  // the one-pass J^T (J x)
  EXPECT_LT((jtjx - dd.transpose() * (dd * x)).norm(), 1e-12 * jtjx.norm());
  const Eigen::MatrixXd gram = dd.transpose() * dd;
  EXPECT_LT((stacked.Gram() - gram).norm(), 1e-12 * gram.norm());
  EXPECT_LT((stacked.ColumnSquaredNorms() - gram.diagonal()).norm(), 1e-12 * gram.diagonal().norm());
  // Both operators over the blocks match the dense ones.
  Eigen::VectorXd a, b, c(dense.cols()), d(dense.cols());
  const MatrixFreeNormalOperator mf(stacked, 0.1), mf_dense(dense, 0.1);
  const AssembledNormalOperator as(stacked, 0.1);
  a.resize(dense.cols());
  b.resize(dense.cols());
  mf.Apply(x, &a);
  as.Apply(x, &b);
  mf_dense.Apply(x, &c);
  EXPECT_LT((a - c).norm(), 1e-12 * c.norm());
  EXPECT_LT((b - c).norm(), 1e-9 * c.norm());
  EXPECT_LT((mf.Diagonal() - mf_dense.Diagonal()).norm(), 1e-12 * c.norm());
  // A block with the wrong width is an error, not a silent misread.
  EXPECT_THROW(stacked.AddFrame(random_jacobian(4, shared + own + 1, 3)), Error);
}

// The products run over fixed chunks of 4096 rows on SetThreads() threads: with blocks of several
// chunks (and a frame boundary inside the stack) they match the dense stack, and every thread
// count gives the same bits.
TEST(TrackerPcg, ThreadedProductsOverSeveralChunksAreBitIdentical) {
  const int shared = 6, own = 4, frames = 2;
  std::vector<JacobianMatrix> blocks{random_jacobian(9000, shared + own, 21), random_jacobian(4100, shared + own, 22)};
  JacobianMatrix dense = JacobianMatrix::Zero(9000 + 4100, shared + frames * own);
  dense.block(0, 0, 9000, shared) = blocks[0].leftCols(shared);
  dense.block(0, shared, 9000, own) = blocks[0].rightCols(own);
  dense.block(9000, 0, 4100, shared) = blocks[1].leftCols(shared);
  dense.block(9000, shared + own, 4100, own) = blocks[1].rightCols(own);
  const Eigen::VectorXd x = Eigen::VectorXd::LinSpaced(dense.cols(), -1, 2);
  const Eigen::VectorXd v = Eigen::VectorXd::LinSpaced(dense.rows(), 3, -1);
  const Eigen::MatrixXd dd = dense.cast<double>();
  Eigen::VectorXd normal[3], transposed[3], diagonal[3];
  for (int threads : {1, 2, 3}) {
    StackedJacobian stacked(shared, own);
    for (const auto& b : blocks) stacked.AddFrame(b);
    stacked.SetThreads(threads);
    stacked.MultiplyNormal(x, &normal[threads - 1]);
    stacked.MultiplyTransposed(v, &transposed[threads - 1]);
    diagonal[threads - 1] = stacked.ColumnSquaredNorms();
    // The fused pass (J^T v and diag(J^T J) together) gives the same bits as the two alone.
    Eigen::VectorXd fused_transposed, fused_diagonal;
    stacked.MultiplyTransposedWithColumnSquaredNorms(v, &fused_transposed, &fused_diagonal);
    EXPECT_TRUE((fused_transposed.array() == transposed[threads - 1].array()).all()) << threads << " threads";
    EXPECT_TRUE((fused_diagonal.array() == diagonal[threads - 1].array()).all()) << threads << " threads";
  }
  EXPECT_LT((normal[0] - dd.transpose() * (dd * x)).norm(), 1e-12 * normal[0].norm());
  EXPECT_LT((transposed[0] - dd.transpose() * v).norm(), 1e-12 * transposed[0].norm());
  EXPECT_LT((diagonal[0] - dd.colwise().squaredNorm().transpose()).norm(), 1e-12 * diagonal[0].norm());
  for (int t : {1, 2}) {
    EXPECT_TRUE((normal[t].array() == normal[0].array()).all()) << t + 1 << " threads";
    EXPECT_TRUE((transposed[t].array() == transposed[0].array()).all()) << t + 1 << " threads";
    EXPECT_TRUE((diagonal[t].array() == diagonal[0].array()).all()) << t + 1 << " threads";
  }
}

// The pass that starts a Gauss-Newton step writes each row's mask of nonzero groups (RowMask),
// and J^T J p then visits only those, chunk by chunk: on frame blocks of several chunks whose rows
// are zero in groups that differ from row to row, the product after that pass has the bits of the
// product before it (every column visited), for any thread count.
TEST(TrackerPcg, TheProductOverTheRowsMasksIsTheWholeRowsProduct) {
  const int shared = 9, own = 14, frames = 2;
  std::vector<JacobianMatrix> blocks{random_jacobian(9000, shared + own, 31), random_jacobian(4500, shared + own, 32)};
  for (JacobianMatrix& b : blocks)
    for (Eigen::Index i = 0; i < b.rows(); ++i)
      for (Eigen::Index k = 0; k + 4 <= b.cols(); k += 4)
        if ((i + k / 4) % 3 != 0) b.row(i).segment(k, 4).setZero();
  const Eigen::VectorXd x = Eigen::VectorXd::LinSpaced(shared + frames * own, -1, 2);
  Eigen::VectorXd v(9000 + 4500);
  for (Eigen::Index i = 0; i < v.size(); ++i) v[i] = std::sin(0.37 * static_cast<double>(i));
  for (int threads : {1, 2, 3}) {
    StackedJacobian stacked(shared, own);
    for (const auto& b : blocks) stacked.AddFrame(b);
    stacked.SetThreads(threads);
    Eigen::VectorXd whole, masked, transposed, diagonal;
    stacked.MultiplyNormal(x, &whole);
    stacked.MultiplyTransposedWithColumnSquaredNorms(v, &transposed, &diagonal);
    stacked.MultiplyNormal(x, &masked);
    EXPECT_TRUE((masked.array() == whole.array()).all()) << threads << " threads";
  }
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
// J^T J p's and J^T v's row loops built for baseline x86-64 and for AVX2 (row_kernels.h) give the same bits
// on rows of every length the solver uses (the tracking layout's 85 columns, a calibration's
// hundreds, lengths that leave a remainder after the four-wide sums), and the choice the program
// makes is one of them.
TEST(RowKernels, TheAvx2VariantGivesTheBaselinesBits) {
  if (!internal::HasAvx2()) GTEST_SKIP() << "this CPU has no AVX2: only the baseline variant runs here";
  std::mt19937 rng(7);
  std::normal_distribution<float> normal(0.f, 1.f);
  for (const Eigen::Index n : {Eigen::Index{1}, Eigen::Index{3}, Eigen::Index{85}, Eigen::Index{87}, Eigen::Index{301}}) {
    const Eigen::Index rows = 257, stride = n + 3;
    std::vector<float> j(static_cast<size_t>(rows * stride));
    for (float& v : j) v = normal(rng) * std::pow(10.f, static_cast<float>(rng() % 7) - 3.f);
    Eigen::VectorXd x(n);
    for (Eigen::Index k = 0; k < n; ++k) x[k] = static_cast<double>(normal(rng));
    Eigen::VectorXd base = Eigen::VectorXd::Constant(n, 0.25), avx2 = base, chosen = base;
    internal::AddNormalRowsBaseline(j.data(), stride, rows, n, nullptr, x.data(), base.data());
    internal::AddNormalRowsAvx2(j.data(), stride, rows, n, nullptr, x.data(), avx2.data());
    internal::AddNormalRows(j.data(), stride, rows, n, nullptr, x.data(), chosen.data());
    for (Eigen::Index k = 0; k < n; ++k) {
      ASSERT_EQ(base[k], avx2[k]) << "n " << n << ", column " << k;
      ASSERT_EQ(base[k], chosen[k]) << "n " << n << ", column " << k;
    }
    // J^T v with diag(J^T J) in one pass.
    Eigen::VectorXd v(rows);
    for (Eigen::Index i = 0; i < rows; ++i) v[i] = static_cast<double>(normal(rng));
    Eigen::VectorXd acc_base = Eigen::VectorXd::Zero(n), sq_base = Eigen::VectorXd::Zero(n);
    Eigen::VectorXd acc_avx2 = acc_base, sq_avx2 = sq_base, acc_chosen = acc_base, sq_chosen = sq_base;
    internal::AddScaledRowsAndSquaresBaseline(j.data(), stride, rows, n, v.data(), acc_base.data(), sq_base.data(),
                                              nullptr);
    internal::AddScaledRowsAndSquaresAvx2(j.data(), stride, rows, n, v.data(), acc_avx2.data(), sq_avx2.data(),
                                          nullptr);
    internal::AddScaledRowsAndSquares(j.data(), stride, rows, n, v.data(), acc_chosen.data(), sq_chosen.data(),
                                      nullptr);
    for (Eigen::Index k = 0; k < n; ++k) {
      ASSERT_EQ(acc_base[k], acc_avx2[k]) << "J^T v, n " << n << ", column " << k;
      ASSERT_EQ(sq_base[k], sq_avx2[k]) << "diag(J^T J), n " << n << ", column " << k;
      ASSERT_EQ(acc_base[k], acc_chosen[k]);
      ASSERT_EQ(sq_base[k], sq_chosen[k]);
    }
  }
}

// The products over each row's nonzero groups of four columns only (RowMask) give the bits of
// the products over whole rows, on rows as sparse as a tracking Jacobian's (most groups zero,
// some holding a -0 or a single nonzero, a row all zeros), in both variants; the masks name
// exactly the groups with a nonzero, and a NaN counts as one.
TEST(RowKernels, TheMaskedProductsGiveTheWholeRowsBits) {
  std::mt19937 rng(11);
  std::normal_distribution<float> normal(0.f, 1.f);
  for (const Eigen::Index n : {Eigen::Index{3}, Eigen::Index{85}, Eigen::Index{175}, internal::kMaxMaskedColumns}) {
    const Eigen::Index rows = 300, stride = n + 1, groups = n / 4;
    std::vector<float> j(static_cast<size_t>(rows * stride), 0.f);
    std::vector<internal::RowMask> expected(static_cast<size_t>(rows), 0);
    for (Eigen::Index i = 1; i < rows; ++i) {  // row 0 stays all zeros
      float* row = j.data() + i * stride;
      for (Eigen::Index g = 0; g < groups; ++g) {
        const uint32_t kind = rng() % 8;
        if (kind == 0) {
          row[4 * g + rng() % 4] = -0.f;
        } else if (kind == 1) {
          row[4 * g + rng() % 4] = normal(rng);
          expected[static_cast<size_t>(i)] |= internal::RowMask{1} << g;
        } else if (kind == 2) {
          for (int l = 0; l < 4; ++l) row[4 * g + l] = normal(rng);
          expected[static_cast<size_t>(i)] |= internal::RowMask{1} << g;
        }
      }
      for (Eigen::Index k = 4 * groups; k < n; ++k) row[k] = rng() % 2 ? normal(rng) : 0.f;
    }
    if (groups > 0) {
      j[static_cast<size_t>(5 * stride)] = std::numeric_limits<float>::quiet_NaN();
      expected[5] |= 1;
    }
    Eigen::VectorXd x(n), v(rows);
    for (Eigen::Index k = 0; k < n; ++k) x[k] = static_cast<double>(normal(rng));
    for (Eigen::Index i = 0; i < rows; ++i) v[i] = static_cast<double>(normal(rng));
    using Squares = void (*)(const float*, Eigen::Index, Eigen::Index, Eigen::Index, const double*, double*, double*,
                             internal::RowMask*);
    using Normal = void (*)(const float*, Eigen::Index, Eigen::Index, Eigen::Index, const internal::RowMask*,
                            const double*, double*);
    std::vector<std::pair<Squares, Normal>> variants = {
        {internal::AddScaledRowsAndSquaresBaseline, internal::AddNormalRowsBaseline},
        {internal::AddScaledRowsAndSquares, internal::AddNormalRows}};
    if (internal::HasAvx2()) variants.push_back({internal::AddScaledRowsAndSquaresAvx2, internal::AddNormalRowsAvx2});
    // Whole rows; the NaN row left out of J^T J p (it makes every sum NaN) by starting past it.
    const Eigen::Index from = 6;
    Eigen::VectorXd acc_whole = Eigen::VectorXd::Zero(n), sq_whole = acc_whole, normal_whole = acc_whole;
    internal::AddScaledRowsAndSquaresBaseline(j.data(), stride, rows, n, v.data(), acc_whole.data(), sq_whole.data(),
                                              nullptr);
    internal::AddNormalRowsBaseline(j.data() + from * stride, stride, rows - from, n, nullptr, x.data(),
                                    normal_whole.data());
    for (const auto& [squares, normal_rows] : variants) {
      std::vector<internal::RowMask> masks(static_cast<size_t>(rows), ~internal::RowMask{0});
      Eigen::VectorXd acc = Eigen::VectorXd::Zero(n), sq = acc, product = acc;
      squares(j.data(), stride, rows, n, v.data(), acc.data(), sq.data(), masks.data());
      normal_rows(j.data() + from * stride, stride, rows - from, n, masks.data() + from, x.data(), product.data());
      for (size_t i = 0; i < masks.size(); ++i) ASSERT_EQ(masks[i], expected[i]) << "row " << i;
      for (Eigen::Index k = 0; k < n; ++k) {
        if (std::isnan(acc_whole[k])) {
          ASSERT_TRUE(std::isnan(acc[k]) && std::isnan(sq[k])) << "n " << n << ", column " << k;
        } else {
          ASSERT_EQ(acc[k], acc_whole[k]) << "J^T v, n " << n << ", column " << k;
          ASSERT_EQ(sq[k], sq_whole[k]) << "diag(J^T J), n " << n << ", column " << k;
        }
        ASSERT_EQ(product[k], normal_whole[k]) << "J^T J p, n " << n << ", column " << k;
      }
    }
  }
}

}  // namespace face_reenact::tracker
