#pragma once
// Checks analytic Jacobians against central finite differences (in the spirit of Ceres'
// GradientChecker), block by block: for every parameter block and residual term, the worst
// relative error over the block's columns,
//   max_j |J_analytic(:, j) - J_numeric(:, j)|_2 / max(|J_numeric(:, j)|_2, absolute_floor).
#include <Eigen/Core>
#include <array>
#include <functional>
#include <string>

#include "face_reenact/tracker/energy.h"

namespace face_reenact::tracker {

struct GradientCheckOptions {
  double relative_step = 1e-6;   // step relative to |x_j|
  double absolute_step = 1e-6;   // h_j = max(absolute_step, relative_step * |x_j|)
  double absolute_floor = 1e-6;  // columns smaller than this compare absolutely
  double tolerance = 1e-4;       // a block fails when its worst relative error exceeds this
  bool IsValid(std::string* why) const;
};

struct GradientCheckResult {
  // worst_error[term][block]; -1 where the term has no rows or the block no columns.
  std::array<std::array<double, kNumBlocks>, kNumTerms> worst_error{};
  double max_error = 0;  // over everything checked
  bool ok = true;        // max_error <= tolerance
  std::string report;    // a table of the above, one line per term
};

using ResidualFunction = std::function<void(const Eigen::VectorXd& x, Eigen::VectorXd* residuals)>;

// Compares `analytic` (rows x layout.num_parameters()) with central differences of `f` at x;
// rows are grouped into terms by `term_rows` (as in Linearization).
GradientCheckResult CompareWithFiniteDifferences(const ResidualFunction& f, const Eigen::VectorXd& x,
                                                 const JacobianMatrix& analytic, const ParameterLayout& layout,
                                                 const std::array<Eigen::Index, kNumTerms + 1>& term_rows,
                                                 const GradientCheckOptions& options);

// The energy's own Jacobian (EvaluateResiduals) checked at x with `lin` held fixed.
GradientCheckResult CheckEnergyJacobian(const TrackerModel& model, const Linearization& lin,
                                        const EnergyOptions& energy_options, const Eigen::VectorXd& x,
                                        const GradientCheckOptions& options);

}  // namespace face_reenact::tracker
