#pragma once
// The CPU solver's row kernels over J (row-major float rows, double accumulation): the inner
// loops of the PCG products (pcg.cc). The J^T J p loop is built twice, for baseline x86-64 and
// for AVX2, and the program picks one by what the CPU has when it first runs it (a Debian package
// must run on baseline x86-64; the build targets it). Both give the same bits: no FMA, and the
// four partial sums of RowDot are the four lanes of one AVX2 register, nothing reassociated.
#include <Eigen/Core>
#include <cstdint>

namespace face_reenact::tracker::internal {

// sum_k row[k] * x[k] in double. Four independent partial sums, so the compiler can keep them in
// one vector register; a single running sum it may not reorder, and would add one at a time.
[[gnu::always_inline]] inline double RowDot(const float* row, const double* x, Eigen::Index n) {
  double s0 = 0, s1 = 0, s2 = 0, s3 = 0;
  Eigen::Index k = 0;
  for (; k + 4 <= n; k += 4) {
    s0 += static_cast<double>(row[k]) * x[k];
    s1 += static_cast<double>(row[k + 1]) * x[k + 1];
    s2 += static_cast<double>(row[k + 2]) * x[k + 2];
    s3 += static_cast<double>(row[k + 3]) * x[k + 3];
  }
  for (; k < n; ++k) s0 += static_cast<double>(row[k]) * x[k];
  return (s0 + s1) + (s2 + s3);
}

// acc[k] += s * row[k] for k < n, in double.
[[gnu::always_inline]] inline void AddScaledRow(double s, const float* row, Eigen::Index n, double* acc) {
  for (Eigen::Index k = 0; k < n; ++k) acc[k] += s * static_cast<double>(row[k]);
}

// Which groups of four columns of a row hold a nonzero: bit g stands for columns 4g .. 4g + 3 (the
// columns past the last whole group are always visited). A tracking row is mostly zeros: on RGB
// video a colour row has its channel's 9 lighting columns and the rotation's 3, and a
// calibration's the albedo's 10 (the colour is differentiated through the projection on RGB-D
// only; on the shared clips 14-22 % of the groups hold a nonzero), so the
// products visit only the groups a row's mask names. Skipping a zero adds nothing that is not
// zero to a partial sum, and RowDot's four sums keep their columns, so the bits are the ones the
// full rows give (for finite x). Rows of up to kMaxMaskedColumns columns have masks.
using RowMask = uint64_t;
constexpr Eigen::Index kMaxMaskedColumns = 4 * 64 + 3;

// acc += sum over `count` rows (`stride` floats apart, `n` used) of row * (row . x): J^T J p's
// inner loop, on the variant this CPU runs best. `masks` (one per row, see RowMask; null: every
// column) says which groups of each row to visit.
void AddNormalRows(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n, const RowMask* masks,
                   const double* x, double* acc);
// acc += sum over `count` rows of v[i] * row and squares += sum of row's squares (J^T v and
// diag(J^T J) in one pass), on the variant this CPU runs best. With `masks` (n at most
// kMaxMaskedColumns), each row's RowMask is written there too, and its zero groups skipped.
void AddScaledRowsAndSquares(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                             const double* v, double* acc, double* squares, RowMask* masks);
// The variants themselves (tests compare them); the AVX2 ones only where HasAvx2().
void AddNormalRowsBaseline(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                           const RowMask* masks, const double* x, double* acc);
void AddNormalRowsAvx2(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                       const RowMask* masks, const double* x, double* acc);
void AddScaledRowsAndSquaresBaseline(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                                     const double* v, double* acc, double* squares, RowMask* masks);
void AddScaledRowsAndSquaresAvx2(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                                 const double* v, double* acc, double* squares, RowMask* masks);
bool HasAvx2();

}  // namespace face_reenact::tracker::internal
