#include "face_reenact/tracker/pcg.h"

#include <cmath>
#include <string>

#include "face_reenact/common/error.h"

namespace face_reenact::tracker {

StackedJacobian::StackedJacobian(int shared, int own) : shared_(shared), own_(own) {
  if (shared < 0 || own < 0) throw Error("stacked Jacobian: negative column count");
}

StackedJacobian::StackedJacobian(const JacobianMatrix& single) : shared_(static_cast<int>(single.cols())), own_(0) {
  AddFrame(single);
}

void StackedJacobian::AddFrame(const JacobianMatrix& block) {
  if (block.cols() != shared_ + own_) {
    throw Error("stacked Jacobian: a frame block has " + std::to_string(block.cols()) + " columns, expected " +
                std::to_string(shared_ + own_));
  }
  blocks_.push_back(&block);
  rows_ += block.rows();
}

const Eigen::VectorXd& StackedJacobian::gather(const Eigen::VectorXd& x, int frame) const {
  if (own_ == 0) return x;  // every column is shared: the frame's x is x
  local_x_.resize(shared_ + own_);
  local_x_.head(shared_) = x.head(shared_);
  local_x_.tail(own_) = x.segment(shared_ + static_cast<Eigen::Index>(frame) * own_, own_);
  return local_x_;
}

void StackedJacobian::scatter_add(const Eigen::VectorXd& local, int frame, Eigen::VectorXd* y) const {
  y->head(shared_) += local.head(shared_);
  if (own_ > 0) y->segment(shared_ + static_cast<Eigen::Index>(frame) * own_, own_) += local.tail(own_);
}

void StackedJacobian::Multiply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const {
  y->resize(rows_);
  Eigen::Index row = 0;
  for (int f = 0; f < num_frames(); ++f) {
    const JacobianMatrix& j = *blocks_[f];
    y->segment(row, j.rows()).noalias() = j * gather(x, f);
    row += j.rows();
  }
}

void StackedJacobian::MultiplyTransposed(const Eigen::VectorXd& v, Eigen::VectorXd* y) const {
  if (num_frames() == 1 && own_ == 0) {
    y->noalias() = blocks_[0]->transpose() * v;
    return;
  }
  y->setZero(cols());
  Eigen::Index row = 0;
  for (int f = 0; f < num_frames(); ++f) {
    const JacobianMatrix& j = *blocks_[f];
    local_y_.noalias() = j.transpose() * v.segment(row, j.rows());
    scatter_add(local_y_, f, y);
    row += j.rows();
  }
}

void StackedJacobian::MultiplyNormal(const Eigen::VectorXd& x, Eigen::VectorXd* y) const {
  y->setZero(cols());
  for (int f = 0; f < num_frames(); ++f) {
    const JacobianMatrix& j = *blocks_[f];
    const Eigen::VectorXd& xl = gather(x, f);
    local_y_.setZero(j.cols());
    for (Eigen::Index i = 0; i < j.rows(); ++i) {
      const auto row = j.row(i);
      local_y_.noalias() += row.dot(xl) * row.transpose();
    }
    scatter_add(local_y_, f, y);
  }
}

Eigen::VectorXd StackedJacobian::ColumnSquaredNorms() const {
  Eigen::VectorXd out = Eigen::VectorXd::Zero(cols());
  for (int f = 0; f < num_frames(); ++f) {
    // Row by row: one streaming pass over the row-major block (a column-wise reduction strides
    // across it).
    const JacobianMatrix& j = *blocks_[f];
    local_y_.setZero(j.cols());
    for (Eigen::Index i = 0; i < j.rows(); ++i) local_y_ += j.row(i).transpose().cwiseAbs2();
    scatter_add(local_y_, f, &out);
  }
  return out;
}

Eigen::MatrixXd StackedJacobian::Gram() const {
  const Eigen::Index n = cols(), local = shared_ + own_;
  Eigen::MatrixXd out = Eigen::MatrixXd::Zero(n, n);
  Eigen::MatrixXd g(local, local);
  for (int f = 0; f < num_frames(); ++f) {
    g.setZero();
    g.selfadjointView<Eigen::Lower>().rankUpdate(blocks_[f]->transpose());
    g.triangularView<Eigen::StrictlyUpper>() = g.transpose();
    const Eigen::Index o = shared_ + static_cast<Eigen::Index>(f) * own_;
    out.topLeftCorner(shared_, shared_) += g.topLeftCorner(shared_, shared_);
    if (own_ > 0) {
      out.block(0, o, shared_, own_) += g.topRightCorner(shared_, own_);
      out.block(o, 0, own_, shared_) += g.bottomLeftCorner(own_, shared_);
      out.block(o, o, own_, own_) += g.bottomRightCorner(own_, own_);
    }
  }
  return out;
}

MatrixFreeNormalOperator::MatrixFreeNormalOperator(const StackedJacobian& jacobian, double damping)
    : jacobian_(jacobian), damping_(damping) {
  diagonal_ = jacobian_.ColumnSquaredNorms();
  diagonal_ *= (1.0 + damping_);
}

void MatrixFreeNormalOperator::Apply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const {
  jacobian_.MultiplyNormal(x, y);
  if (damping_ > 0) y->array() += (damping_ / (1.0 + damping_)) * diagonal_.array() * x.array();
}

AssembledNormalOperator::AssembledNormalOperator(const StackedJacobian& jacobian, double damping)
    : matrix_(jacobian.Gram()) {
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
  // The solver starts from zero, where A x is zero without a pass over J.
  if (x->isZero(0.0))
    s->q.setZero();
  else
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
