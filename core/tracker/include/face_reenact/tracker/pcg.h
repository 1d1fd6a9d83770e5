#pragma once
// Preconditioned conjugate gradients on the (damped) normal equations
//   (J^T J + D) dx = -J^T r,  D = lambda * diag(J^T J),
// written once over a linear-operator interface so that the same loop runs with J applied
// twice per iteration (matrix-free, the paper's Sec. 6.2) or with J^T J assembled once. The
// preconditioner is Jacobi: the inverse of diag(J^T J + D). Nothing allocates inside Pcg().
#include <Eigen/Core>
#include <string>

#include "face_reenact/tracker/energy.h"

namespace face_reenact::tracker {

class NormalOperator {
 public:
  virtual ~NormalOperator() = default;
  virtual Eigen::Index size() const = 0;
  // y = (J^T J + D) x; y is already sized.
  virtual void Apply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const = 0;
  // diag(J^T J + D).
  virtual const Eigen::VectorXd& Diagonal() const = 0;
};

// Applies J then J^T; owns one residual-sized scratch vector.
class MatrixFreeNormalOperator final : public NormalOperator {
 public:
  MatrixFreeNormalOperator(const JacobianMatrix& jacobian, double damping);
  Eigen::Index size() const override { return jacobian_.cols(); }
  void Apply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const override;
  const Eigen::VectorXd& Diagonal() const override { return diagonal_; }

 private:
  const JacobianMatrix& jacobian_;
  double damping_;
  Eigen::VectorXd diagonal_;
  mutable Eigen::VectorXd jx_;
};

// Assembles A = J^T J + D once (exploiting symmetry).
class AssembledNormalOperator final : public NormalOperator {
 public:
  AssembledNormalOperator(const JacobianMatrix& jacobian, double damping);
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
