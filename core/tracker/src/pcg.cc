#include "face_reenact/tracker/pcg.h"

#include <cmath>

namespace face_reenact::tracker {

MatrixFreeNormalOperator::MatrixFreeNormalOperator(const JacobianMatrix& jacobian, double damping)
    : jacobian_(jacobian), damping_(damping), jx_(jacobian.rows()) {
  diagonal_ = jacobian.colwise().squaredNorm().transpose();
  diagonal_ *= (1.0 + damping_);
}

void MatrixFreeNormalOperator::Apply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const {
  jx_.noalias() = jacobian_ * x;
  y->noalias() = jacobian_.transpose() * jx_;
  if (damping_ > 0) y->array() += (damping_ / (1.0 + damping_)) * diagonal_.array() * x.array();
}

AssembledNormalOperator::AssembledNormalOperator(const JacobianMatrix& jacobian, double damping) {
  const Eigen::Index n = jacobian.cols();
  matrix_ = Eigen::MatrixXd::Zero(n, n);
  matrix_.selfadjointView<Eigen::Lower>().rankUpdate(jacobian.transpose());
  matrix_.triangularView<Eigen::StrictlyUpper>() = matrix_.transpose();
  diagonal_ = matrix_.diagonal() * (1.0 + damping);
  matrix_.diagonal() = diagonal_;
}

void AssembledNormalOperator::Apply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const { y->noalias() = matrix_ * x; }

bool PcgOptions::IsValid(std::string* why) const {
  if (max_iterations < 1 || max_iterations > 10000) {
    if (why) *why = "PCG: max_iterations must be 1..10000";
    return false;
  }
  if (!(relative_tolerance >= 0)) {
    if (why) *why = "PCG: relative_tolerance must be non-negative";
    return false;
  }
  return true;
}

void PcgScratch::Resize(Eigen::Index n) {
  r.resize(n);
  z.resize(n);
  p.resize(n);
  q.resize(n);
  inverse_diagonal.resize(n);
}

PcgSummary Pcg(const NormalOperator& a, const Eigen::VectorXd& b, const PcgOptions& options, PcgScratch* s,
               Eigen::VectorXd* x) {
  PcgSummary summary;
  const Eigen::VectorXd& diag = a.Diagonal();
  // Jacobi preconditioner; columns the data does not touch (zero diagonal) are left alone.
  for (Eigen::Index k = 0; k < diag.size(); ++k) s->inverse_diagonal[k] = diag[k] > 0 ? 1.0 / diag[k] : 0.0;
  a.Apply(*x, &s->q);
  s->r = b - s->q;
  const double b_norm = b.norm();
  summary.initial_residual_norm = s->r.norm();
  summary.final_residual_norm = summary.initial_residual_norm;
  if (b_norm == 0 || summary.initial_residual_norm <= options.relative_tolerance * b_norm) {
    summary.converged = true;
    return summary;
  }
  s->z = s->inverse_diagonal.cwiseProduct(s->r);
  s->p = s->z;
  double rz = s->r.dot(s->z);
  for (int it = 0; it < options.max_iterations; ++it) {
    a.Apply(s->p, &s->q);
    const double pq = s->p.dot(s->q);
    if (!(pq > 0) || !std::isfinite(pq)) break;  // direction of no curvature: stop with what we have
    const double step = rz / pq;
    *x += step * s->p;
    s->r -= step * s->q;
    summary.iterations = it + 1;
    summary.final_residual_norm = s->r.norm();
    if (summary.final_residual_norm <= options.relative_tolerance * b_norm) {
      summary.converged = true;
      break;
    }
    s->z = s->inverse_diagonal.cwiseProduct(s->r);
    const double rz_next = s->r.dot(s->z);
    s->p = s->z + (rz_next / rz) * s->p;
    rz = rz_next;
  }
  return summary;
}

}  // namespace face_reenact::tracker
