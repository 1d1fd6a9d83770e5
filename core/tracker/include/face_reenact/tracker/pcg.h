#pragma once
// Preconditioned conjugate gradients on the (damped) normal equations
//   (J^T J + D) dx = -J^T r,  D = lambda * diag(J^T J),
// written once over a linear-operator interface so that the same loop runs with J applied
// twice per iteration (matrix-free, the paper's Sec. 6.2) or with J^T J assembled once. The
// preconditioner is Jacobi: the inverse of diag(J^T J + D). Nothing allocates inside Pcg().
#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "face_reenact/tracker/energy.h"

namespace face_reenact::tracker {

// The Jacobian of a joint multi-frame problem (calibration, Sec. 6.3) stored without its zeros:
// frame f's rows touch only the shared columns [0, shared) (identity, albedo) and the frame's own
// [shared + f * own, shared + (f + 1) * own) (expression, lighting, pose). Each frame's block is
// a dense JacobianMatrix over its local columns (shared, then own: one frame's x). Stacking them
// densely instead would store and multiply mostly zeros (5 frames: 3x the flops, 266 MB at
// 640x480). One frame is an ordinary Jacobian. The blocks are referenced, not copied.
class StackedJacobian {
 public:
  StackedJacobian(int shared, int own);
  explicit StackedJacobian(const JacobianMatrix& single);  // one frame, all columns shared
  // Appends the next frame's block (shared + own columns).
  void AddFrame(const JacobianMatrix& block);
  // Threads for the products below (default 1). They go over fixed chunks of rows whose partial
  // sums are added in order, so the results are bit-identical for any thread count. They read
  // J's floats and accumulate in double.
  void SetThreads(int threads) { threads_ = threads < 1 ? 1 : threads; }
  int num_frames() const { return static_cast<int>(blocks_.size()); }
  Eigen::Index rows() const { return rows_; }
  Eigen::Index cols() const { return shared_ + static_cast<Eigen::Index>(num_frames()) * own_; }
  // y = J x (y is resized to rows()); rows are the frames' rows in order.
  void Multiply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const;
  // y = J^T v (y is resized to cols()).
  void MultiplyTransposed(const Eigen::VectorXd& v, Eigen::VectorXd* y) const;
  // y = J^T (J x) (y is resized to cols()) in one pass over J: row by row, (J_i . x) J_i^T is
  // added. J is the largest thing the PCG touches (4.5 MB of floats at 640x480's level 2) and
  // on CPUs the products are bound by memory bandwidth, so one pass instead of Multiply's and
  // MultiplyTransposed's two halves their cost.
  void MultiplyNormal(const Eigen::VectorXd& x, Eigen::VectorXd* y) const;
  // diag(J^T J).
  Eigen::VectorXd ColumnSquaredNorms() const;
  // y = J^T v and diag(J^T J) in one pass over J (a Gauss-Newton step needs both before the
  // PCG starts), bit-identical to MultiplyTransposed and ColumnSquaredNorms.
  void MultiplyTransposedWithColumnSquaredNorms(const Eigen::VectorXd& v, Eigen::VectorXd* y,
                                                Eigen::VectorXd* column_squared_norms) const;
  // J^T J, summed block by block.
  Eigen::MatrixXd Gram() const;

 private:
  // Rows [begin, end) of one frame's block; `first` is the first row's index in the stack.
  struct RowChunk {
    int frame = 0;
    Eigen::Index begin = 0, end = 0, first = 0;
  };
  // The frame's local x: the shared entries, then its own.
  const Eigen::VectorXd& gather(const Eigen::VectorXd& x, int frame) const;
  void scatter_add(const Eigen::Ref<const Eigen::VectorXd>& local, int frame, Eigen::VectorXd* y) const;
  // partials_[k] = chunk_sum(chunks_[k], partials_[k]) for every chunk (on threads_ threads),
  // then y = the partials scattered and added in chunk order.
  void SumOverChunks(const std::function<void(const RowChunk&, Eigen::VectorXd*)>& chunk_sum,
                     Eigen::VectorXd* y) const;

  int shared_, own_;
  int threads_ = 1;
  Eigen::Index rows_ = 0;
  std::vector<const JacobianMatrix*> blocks_;
  std::vector<RowChunk> chunks_;
  mutable std::vector<Eigen::VectorXd> local_x_, partials_;
  // Per chunk, which groups of four columns of each row hold a nonzero (row_kernels.h, RowMask),
  // written by MultiplyTransposedWithColumnSquaredNorms, the pass every Gauss-Newton step starts
  // with, and read by MultiplyNormal, which then visits only those (empty: every column). The
  // blocks are the caller's and must not change while this view of them lives (as everywhere).
  mutable std::vector<std::vector<uint64_t>> masks_;
};

class NormalOperator {
 public:
  virtual ~NormalOperator() = default;
  virtual Eigen::Index size() const = 0;
  // y = (J^T J + D) x; y is already sized.
  virtual void Apply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const = 0;
  // diag(J^T J + D).
  virtual const Eigen::VectorXd& Diagonal() const = 0;
};

// Applies J^T J without forming it (StackedJacobian::MultiplyNormal: one pass over J).
class MatrixFreeNormalOperator final : public NormalOperator {
 public:
  MatrixFreeNormalOperator(const StackedJacobian& jacobian, double damping);
  // With diag(J^T J) already computed (StackedJacobian::MultiplyTransposedWithColumnSquaredNorms).
  MatrixFreeNormalOperator(const StackedJacobian& jacobian, double damping,
                           const Eigen::VectorXd& column_squared_norms);
  MatrixFreeNormalOperator(const JacobianMatrix& jacobian, double damping)
      : MatrixFreeNormalOperator(StackedJacobian(jacobian), damping) {}
  Eigen::Index size() const override { return jacobian_.cols(); }
  void Apply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const override;
  const Eigen::VectorXd& Diagonal() const override { return diagonal_; }

 private:
  StackedJacobian jacobian_;  // a view: the blocks stay the caller's
  double damping_;
  Eigen::VectorXd diagonal_;
};

// Assembles A = J^T J + D once (exploiting symmetry).
class AssembledNormalOperator final : public NormalOperator {
 public:
  AssembledNormalOperator(const StackedJacobian& jacobian, double damping);
  // From J^T J already formed (the Vulkan calibration sums it over frames).
  AssembledNormalOperator(Eigen::MatrixXd gram, double damping);
  AssembledNormalOperator(const JacobianMatrix& jacobian, double damping)
      : AssembledNormalOperator(StackedJacobian(jacobian), damping) {}
  Eigen::Index size() const override { return matrix_.cols(); }
  void Apply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const override;
  const Eigen::VectorXd& Diagonal() const override { return diagonal_; }
  const Eigen::MatrixXd& matrix() const { return matrix_; }

 private:
  Eigen::MatrixXd matrix_;
  Eigen::VectorXd diagonal_;
};

struct PcgOptions {
  int max_iterations = 4;
  double relative_tolerance = 1e-10;  // stop when |b - A x| <= tol * |b|
  bool IsValid(std::string* why) const;
};

struct PcgSummary {
  int iterations = 0;
  double initial_residual_norm = 0;
  double final_residual_norm = 0;
  bool converged = false;  // reached relative_tolerance (or b == 0)
};

struct PcgScratch {
  Eigen::VectorXd r, z, p, q, inverse_diagonal;
  void Resize(Eigen::Index n);
};

// Solves A x = b from the x given (normally zero). `scratch` must be Resize()d to A's size.
PcgSummary Pcg(const NormalOperator& a, const Eigen::VectorXd& b, const PcgOptions& options, PcgScratch* scratch,
               Eigen::VectorXd* x);

}  // namespace face_reenact::tracker
