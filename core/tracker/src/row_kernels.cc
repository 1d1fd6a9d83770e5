// The row kernels' variants and the choice between them (row_kernels.h).
#include "row_kernels.h"

namespace face_reenact::tracker::internal {

namespace {

[[gnu::always_inline]] inline void add_normal_rows(const float* rows, Eigen::Index stride, Eigen::Index count,
                                                   Eigen::Index n, const double* x, double* acc) {
  for (Eigen::Index i = 0; i < count; ++i) {
    const float* row = rows + i * stride;
    AddScaledRow(RowDot(row, x, n), row, n, acc);
  }
}

[[gnu::always_inline]] inline void add_scaled_rows_and_squares(const float* rows, Eigen::Index stride,
                                                               Eigen::Index count, Eigen::Index n, const double* v,
                                                               double* acc, double* squares) {
  for (Eigen::Index i = 0; i < count; ++i) {
    const float* row = rows + i * stride;
    AddScaledRow(v[i], row, n, acc);
    for (Eigen::Index q = 0; q < n; ++q) squares[q] += static_cast<double>(row[q]) * static_cast<double>(row[q]);
  }
}

}  // namespace

void AddScaledRowsAndSquaresBaseline(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                                     const double* v, double* acc, double* squares) {
  add_scaled_rows_and_squares(rows, stride, count, n, v, acc, squares);
}

void AddNormalRowsBaseline(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                           const double* x, double* acc) {
  add_normal_rows(rows, stride, count, n, x, acc);
}

#if defined(__x86_64__) && (defined(__clang__) || defined(__GNUC__))
__attribute__((target("avx2"))) void AddNormalRowsAvx2(const float* rows, Eigen::Index stride, Eigen::Index count,
                                                       Eigen::Index n, const double* x, double* acc) {
  add_normal_rows(rows, stride, count, n, x, acc);
}

__attribute__((target("avx2"))) void AddScaledRowsAndSquaresAvx2(const float* rows, Eigen::Index stride,
                                                                 Eigen::Index count, Eigen::Index n, const double* v,
                                                                 double* acc, double* squares) {
  add_scaled_rows_and_squares(rows, stride, count, n, v, acc, squares);
}

bool HasAvx2() {
  static const bool has = [] {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") != 0;
  }();
  return has;
}
#else
void AddNormalRowsAvx2(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n, const double* x,
                       double* acc) {
  add_normal_rows(rows, stride, count, n, x, acc);
}

void AddScaledRowsAndSquaresAvx2(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                                 const double* v, double* acc, double* squares) {
  add_scaled_rows_and_squares(rows, stride, count, n, v, acc, squares);
}

bool HasAvx2() { return false; }
#endif

void AddNormalRows(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n, const double* x,
                   double* acc) {
  if (HasAvx2()) {
    AddNormalRowsAvx2(rows, stride, count, n, x, acc);
  } else {
    AddNormalRowsBaseline(rows, stride, count, n, x, acc);
  }
}

void AddScaledRowsAndSquares(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                             const double* v, double* acc, double* squares) {
  if (HasAvx2()) {
    AddScaledRowsAndSquaresAvx2(rows, stride, count, n, v, acc, squares);
  } else {
    AddScaledRowsAndSquaresBaseline(rows, stride, count, n, v, acc, squares);
  }
}

}  // namespace face_reenact::tracker::internal
