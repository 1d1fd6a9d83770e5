#include "face_reenact/tracker/pcg.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "row_kernels.h"

namespace face_reenact::tracker {

StackedJacobian::StackedJacobian(int shared, int own) : shared_(shared), own_(own) {
  if (shared < 0 || own < 0) throw Error("stacked Jacobian: negative column count");
}

StackedJacobian::StackedJacobian(const JacobianMatrix& single) : shared_(static_cast<int>(single.cols())), own_(0) {
  AddFrame(single);
}

namespace {
// Rows per chunk of the products: 4096 rows of 85 floats are 1.4 MB, so 640x480's level 2
// (13k rows) splits into 4 chunks and level 1 (53k) into 13.
constexpr Eigen::Index kRowsPerChunk = 4096;
// Rows converted to double at a time by the products that hand J to Eigen's kernels (Gram):
// 256 rows of 85 doubles stay in L2.
constexpr Eigen::Index kRowsPerTile = 256;

}  // namespace

void StackedJacobian::AddFrame(const JacobianMatrix& block) {
  if (block.cols() != shared_ + own_) {
    throw Error("stacked Jacobian: a frame block has " + std::to_string(block.cols()) + " columns, expected " +
                std::to_string(shared_ + own_));
  }
  const int frame = num_frames();
  for (Eigen::Index begin = 0; begin < block.rows(); begin += kRowsPerChunk) {
    chunks_.push_back({frame, begin, std::min(block.rows(), begin + kRowsPerChunk), rows_ + begin});
  }
  blocks_.push_back(&block);
  local_x_.emplace_back();
  rows_ += block.rows();
  partials_.resize(chunks_.size());
  masks_.resize(chunks_.size());
}

const Eigen::VectorXd& StackedJacobian::gather(const Eigen::VectorXd& x, int frame) const {
  if (own_ == 0) return x;  // every column is shared: the frame's x is x
  Eigen::VectorXd& local = local_x_[static_cast<size_t>(frame)];
  local.resize(shared_ + own_);
  local.head(shared_) = x.head(shared_);
  local.tail(own_) = x.segment(shared_ + static_cast<Eigen::Index>(frame) * own_, own_);
  return local;
}

void StackedJacobian::scatter_add(const Eigen::Ref<const Eigen::VectorXd>& local, int frame, Eigen::VectorXd* y) const {
  y->head(shared_) += local.head(shared_);
  if (own_ > 0) y->segment(shared_ + static_cast<Eigen::Index>(frame) * own_, own_) += local.tail(own_);
}

void StackedJacobian::SumOverChunks(const std::function<void(const RowChunk&, Eigen::VectorXd*)>& chunk_sum,
                                    Eigen::VectorXd* y) const {
  ParallelFor(static_cast<int>(chunks_.size()), threads_, [&](int k) {
    Eigen::VectorXd& partial = partials_[static_cast<size_t>(k)];
    partial.setZero(shared_ + own_);
    chunk_sum(chunks_[static_cast<size_t>(k)], &partial);
  });
  y->setZero(cols());
  for (size_t k = 0; k < chunks_.size(); ++k) scatter_add(partials_[k], chunks_[k].frame, y);
}

void StackedJacobian::Multiply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const {
  y->resize(rows_);
  Eigen::Index row = 0;
  for (int f = 0; f < num_frames(); ++f) {
    const JacobianMatrix& j = *blocks_[f];
    y->segment(row, j.rows()).noalias() = j.cast<double>() * gather(x, f);
    row += j.rows();
  }
}

void StackedJacobian::MultiplyTransposed(const Eigen::VectorXd& v, Eigen::VectorXd* y) const {
  SumOverChunks(
      [&](const RowChunk& c, Eigen::VectorXd* partial) {
        const JacobianMatrix& j = *blocks_[c.frame];
        for (Eigen::Index i = c.begin; i < c.end; ++i) {
          internal::AddScaledRow(v[c.first + (i - c.begin)], j.row(i).data(), j.cols(), partial->data());
        }
      },
      y);
}

void StackedJacobian::MultiplyNormal(const Eigen::VectorXd& x, Eigen::VectorXd* y) const {
  for (int f = 0; f < num_frames(); ++f) gather(x, f);  // before the threads: each reads its frame's
  SumOverChunks(
      [&](const RowChunk& c, Eigen::VectorXd* partial) {
        const JacobianMatrix& j = *blocks_[c.frame];
        const Eigen::VectorXd& xl = own_ == 0 ? x : local_x_[static_cast<size_t>(c.frame)];
        const std::vector<uint64_t>& masks = masks_[static_cast<size_t>(&c - chunks_.data())];
        if (c.end > c.begin)
          internal::AddNormalRows(j.row(c.begin).data(), j.outerStride(), c.end - c.begin, j.cols(),
                                  masks.size() == static_cast<size_t>(c.end - c.begin) ? masks.data() : nullptr,
                                  xl.data(), partial->data());
      },
      y);
}

Eigen::VectorXd StackedJacobian::ColumnSquaredNorms() const {
  // Row by row: one streaming pass over the row-major block (a column-wise reduction strides
  // across it).
  Eigen::VectorXd out;
  SumOverChunks(
      [&](const RowChunk& c, Eigen::VectorXd* partial) {
        const JacobianMatrix& j = *blocks_[c.frame];
        double* acc = partial->data();
        for (Eigen::Index i = c.begin; i < c.end; ++i) {
          const float* row = j.row(i).data();
          for (Eigen::Index k = 0; k < j.cols(); ++k) acc[k] += static_cast<double>(row[k]) * static_cast<double>(row[k]);
        }
      },
      &out);
  return out;
}

void StackedJacobian::MultiplyTransposedWithColumnSquaredNorms(const Eigen::VectorXd& v, Eigen::VectorXd* y,
                                                               Eigen::VectorXd* column_squared_norms) const {
  // Each chunk's partial holds J^T v, then diag(J^T J), each summed as the single products do.
  const Eigen::Index local = shared_ + own_;
  ParallelFor(static_cast<int>(chunks_.size()), threads_, [&](int k) {
    const RowChunk& c = chunks_[static_cast<size_t>(k)];
    Eigen::VectorXd& partial = partials_[static_cast<size_t>(k)];
    partial.setZero(2 * local);
    const JacobianMatrix& j = *blocks_[c.frame];
    double* norms = partial.data() + local;
    std::vector<uint64_t>& masks = masks_[static_cast<size_t>(k)];
    masks.resize(local <= internal::kMaxMaskedColumns ? static_cast<size_t>(c.end - c.begin) : 0);
    if (c.end > c.begin)
      internal::AddScaledRowsAndSquares(j.row(c.begin).data(), j.outerStride(), c.end - c.begin, local, v.data() + c.first,
                                        partial.data(), norms, masks.empty() ? nullptr : masks.data());
  });
  y->setZero(cols());
  column_squared_norms->setZero(cols());
  for (size_t k = 0; k < chunks_.size(); ++k) {
    scatter_add(partials_[k].head(local), chunks_[k].frame, y);
    scatter_add(partials_[k].tail(local), chunks_[k].frame, column_squared_norms);
  }
}

Eigen::MatrixXd StackedJacobian::Gram() const {
  const Eigen::Index n = cols(), local = shared_ + own_;
  Eigen::MatrixXd out = Eigen::MatrixXd::Zero(n, n);
  Eigen::MatrixXd g(local, local);
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> tile;
  for (int f = 0; f < num_frames(); ++f) {
    g.setZero();
    const JacobianMatrix& j = *blocks_[f];
    for (Eigen::Index begin = 0; begin < j.rows(); begin += kRowsPerTile) {
      tile = j.middleRows(begin, std::min(kRowsPerTile, j.rows() - begin)).cast<double>();
      g.selfadjointView<Eigen::Lower>().rankUpdate(tile.transpose());
    }
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

MatrixFreeNormalOperator::MatrixFreeNormalOperator(const StackedJacobian& jacobian, double damping,
                                                   const Eigen::VectorXd& column_squared_norms)
    : jacobian_(jacobian), damping_(damping), diagonal_(column_squared_norms) {
  if (diagonal_.size() != jacobian_.cols()) throw Error("matrix-free operator: the diagonal has the wrong size");
  diagonal_ *= (1.0 + damping_);
}

void MatrixFreeNormalOperator::Apply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const {
  jacobian_.MultiplyNormal(x, y);
  if (damping_ > 0) y->array() += (damping_ / (1.0 + damping_)) * diagonal_.array() * x.array();
}

AssembledNormalOperator::AssembledNormalOperator(const StackedJacobian& jacobian, double damping)
    : AssembledNormalOperator(jacobian.Gram(), damping) {}

AssembledNormalOperator::AssembledNormalOperator(Eigen::MatrixXd gram, double damping) : matrix_(std::move(gram)) {
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
