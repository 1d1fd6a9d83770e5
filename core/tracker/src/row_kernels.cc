// The row kernels' variants and the choice between them (row_kernels.h).
#include "row_kernels.h"

#include <cstring>

namespace face_reenact::tracker::internal {

namespace {

// Four columns at a time in GCC's vector types: the baseline build does each as two SSE2 halves,
// the AVX2 one as one register, with the same operations per lane (no FMA in either target).
typedef float Floats4 __attribute__((vector_size(16)));
typedef double Doubles4 __attribute__((vector_size(32)));

[[gnu::always_inline]] inline Floats4 load_floats4(const float* p) {
  Floats4 v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}
// acc[0..3] += a * b[0..3] (through pointers: a 32-byte vector passed by value would be an
// AVX argument, which the baseline build's ABI does not have).
[[gnu::always_inline]] inline void add_product4(double* acc, const Doubles4* a, const Doubles4* b) {
  Doubles4 v;
  std::memcpy(&v, acc, sizeof(v));
  v += *a * *b;
  std::memcpy(acc, &v, sizeof(v));
}
[[gnu::always_inline]] inline bool any_nonzero(Floats4 v) {
  const auto nonzero = v != Floats4{0.f, 0.f, 0.f, 0.f};  // NaN counts as nonzero
  return (nonzero[0] | nonzero[1] | nonzero[2] | nonzero[3]) != 0;
}

[[gnu::always_inline]] inline void add_normal_rows(const float* rows, Eigen::Index stride, Eigen::Index count,
                                                   Eigen::Index n, const double* x, double* acc) {
  for (Eigen::Index i = 0; i < count; ++i) {
    const float* row = rows + i * stride;
    AddScaledRow(RowDot(row, x, n), row, n, acc);
  }
}

// add_normal_rows over the groups each row's mask names: RowDot's four sums are the four lanes,
// its remainder goes to the first, and its closing sum is the same.
[[gnu::always_inline]] inline void add_normal_rows_masked(const float* rows, Eigen::Index stride, Eigen::Index count,
                                                          Eigen::Index n, const RowMask* masks, const double* x,
                                                          double* acc) {
  const Eigen::Index whole = n / 4 * 4;
  for (Eigen::Index i = 0; i < count; ++i) {
    const float* row = rows + i * stride;
    const RowMask mask = masks[i];
    Doubles4 sums{0.0, 0.0, 0.0, 0.0};
    for (RowMask m = mask; m != 0; m &= m - 1) {
      const Eigen::Index k = 4 * __builtin_ctzll(m);
      Doubles4 xk;
      std::memcpy(&xk, x + k, sizeof(xk));
      sums += __builtin_convertvector(load_floats4(row + k), Doubles4) * xk;
    }
    double s0 = sums[0];
    for (Eigen::Index k = whole; k < n; ++k) s0 += static_cast<double>(row[k]) * x[k];
    const double dot = (s0 + sums[1]) + (sums[2] + sums[3]);
    const Doubles4 scale{dot, dot, dot, dot};
    for (RowMask m = mask; m != 0; m &= m - 1) {
      const Eigen::Index k = 4 * __builtin_ctzll(m);
      const Doubles4 d = __builtin_convertvector(load_floats4(row + k), Doubles4);
      add_product4(acc + k, &scale, &d);
    }
    for (Eigen::Index k = whole; k < n; ++k) acc[k] += dot * static_cast<double>(row[k]);
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

// The same sums, skipping the groups of four zeros, whose mask it writes.
[[gnu::always_inline]] inline void add_scaled_rows_and_squares_masked(const float* rows, Eigen::Index stride,
                                                                      Eigen::Index count, Eigen::Index n,
                                                                      const double* v, double* acc, double* squares,
                                                                      RowMask* masks) {
  const Eigen::Index whole = n / 4 * 4;
  for (Eigen::Index i = 0; i < count; ++i) {
    const float* row = rows + i * stride;
    const Doubles4 scale{v[i], v[i], v[i], v[i]};
    RowMask mask = 0;
    for (Eigen::Index k = 0; k < whole; k += 4) {
      const Floats4 f = load_floats4(row + k);
      if (!any_nonzero(f)) continue;
      mask |= RowMask{1} << (k / 4);
      const Doubles4 d = __builtin_convertvector(f, Doubles4);
      add_product4(acc + k, &scale, &d);
      add_product4(squares + k, &d, &d);
    }
    for (Eigen::Index k = whole; k < n; ++k) {
      acc[k] += v[i] * static_cast<double>(row[k]);
      squares[k] += static_cast<double>(row[k]) * static_cast<double>(row[k]);
    }
    masks[i] = mask;
  }
}

[[gnu::always_inline]] inline void normal_rows(const float* rows, Eigen::Index stride, Eigen::Index count,
                                               Eigen::Index n, const RowMask* masks, const double* x, double* acc) {
  if (masks) {
    add_normal_rows_masked(rows, stride, count, n, masks, x, acc);
  } else {
    add_normal_rows(rows, stride, count, n, x, acc);
  }
}

[[gnu::always_inline]] inline void scaled_rows_and_squares(const float* rows, Eigen::Index stride, Eigen::Index count,
                                                           Eigen::Index n, const double* v, double* acc,
                                                           double* squares, RowMask* masks) {
  if (masks) {
    add_scaled_rows_and_squares_masked(rows, stride, count, n, v, acc, squares, masks);
  } else {
    add_scaled_rows_and_squares(rows, stride, count, n, v, acc, squares);
  }
}

}  // namespace

void AddScaledRowsAndSquaresBaseline(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                                     const double* v, double* acc, double* squares, RowMask* masks) {
  scaled_rows_and_squares(rows, stride, count, n, v, acc, squares, masks);
}

void AddNormalRowsBaseline(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                           const RowMask* masks, const double* x, double* acc) {
  normal_rows(rows, stride, count, n, masks, x, acc);
}

#if defined(__x86_64__) && (defined(__clang__) || defined(__GNUC__))
__attribute__((target("avx2"))) void AddNormalRowsAvx2(const float* rows, Eigen::Index stride, Eigen::Index count,
                                                       Eigen::Index n, const RowMask* masks, const double* x,
                                                       double* acc) {
  normal_rows(rows, stride, count, n, masks, x, acc);
}

__attribute__((target("avx2"))) void AddScaledRowsAndSquaresAvx2(const float* rows, Eigen::Index stride,
                                                                 Eigen::Index count, Eigen::Index n, const double* v,
                                                                 double* acc, double* squares, RowMask* masks) {
  scaled_rows_and_squares(rows, stride, count, n, v, acc, squares, masks);
}

bool HasAvx2() {
  static const bool has = [] {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") != 0;
  }();
  return has;
}
#else
void AddNormalRowsAvx2(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                       const RowMask* masks, const double* x, double* acc) {
  normal_rows(rows, stride, count, n, masks, x, acc);
}

void AddScaledRowsAndSquaresAvx2(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                                 const double* v, double* acc, double* squares, RowMask* masks) {
  scaled_rows_and_squares(rows, stride, count, n, v, acc, squares, masks);
}

bool HasAvx2() { return false; }
#endif

void AddNormalRows(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n, const RowMask* masks,
                   const double* x, double* acc) {
  if (HasAvx2()) {
    AddNormalRowsAvx2(rows, stride, count, n, masks, x, acc);
  } else {
    AddNormalRowsBaseline(rows, stride, count, n, masks, x, acc);
  }
}

void AddScaledRowsAndSquares(const float* rows, Eigen::Index stride, Eigen::Index count, Eigen::Index n,
                             const double* v, double* acc, double* squares, RowMask* masks) {
  if (HasAvx2()) {
    AddScaledRowsAndSquaresAvx2(rows, stride, count, n, v, acc, squares, masks);
  } else {
    AddScaledRowsAndSquaresBaseline(rows, stride, count, n, v, acc, squares, masks);
  }
}

}  // namespace face_reenact::tracker::internal
