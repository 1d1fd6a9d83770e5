#include "face_reenact/tracker/gradient_checker.h"

#include <cmath>
#include <cstdio>

#include "face_reenact/common/error.h"

namespace face_reenact::tracker {

bool GradientCheckOptions::IsValid(std::string* why) const {
  if (!(relative_step > 0) || !(absolute_step > 0) || !(absolute_floor > 0) || !(tolerance > 0)) {
    if (why) *why = "gradient check: steps, floor and tolerance must be positive";
    return false;
  }
  return true;
}

GradientCheckResult CompareWithFiniteDifferences(const ResidualFunction& f, const Eigen::VectorXd& x,
                                                 const JacobianMatrix& analytic, const ParameterLayout& layout,
                                                 const std::array<Eigen::Index, kNumTerms + 1>& term_rows,
                                                 const GradientCheckOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  const Eigen::Index m = term_rows[kNumTerms];
  if (x.size() != layout.num_parameters() || analytic.cols() != x.size() || analytic.rows() != m) {
    throw Error("gradient check: Jacobian, parameters and row layout disagree in size");
  }
  GradientCheckResult result;
  for (auto& row : result.worst_error) row.fill(-1.0);
  Eigen::VectorXd xp = x, rp, rm, numeric;
  for (int b = 0; b < kNumBlocks; ++b) {
    const Block block = static_cast<Block>(b);
    for (int q = 0; q < layout.size(block); ++q) {
      const int col = layout.offset(block) + q;
      const double h = std::max(options.absolute_step, options.relative_step * std::abs(x[col]));
      xp[col] = x[col] + h;
      f(xp, &rp);
      xp[col] = x[col] - h;
      f(xp, &rm);
      xp[col] = x[col];
      if (rp.size() != m || rm.size() != m) throw Error("gradient check: residual function changed its row count");
      numeric = (rp - rm) / (2 * h);
      for (int t = 0; t < kNumTerms; ++t) {
        const Eigen::Index begin = term_rows[t], rows = term_rows[t + 1] - term_rows[t];
        if (rows == 0) continue;
        const Eigen::VectorXd num = numeric.segment(begin, rows);
        const Eigen::VectorXd ana = analytic.col(col).segment(begin, rows).cast<double>();
        const double err = (ana - num).norm() / std::max(num.norm(), options.absolute_floor);
        double& worst = result.worst_error[t][b];
        worst = std::max(worst, err);
        result.max_error = std::max(result.max_error, err);
      }
    }
  }
  result.ok = result.max_error <= options.tolerance;
  std::string report = "worst relative Jacobian error (term x block):\n            ";
  char buf[64];
  for (int b = 0; b < kNumBlocks; ++b) {
    std::snprintf(buf, sizeof(buf), " %11s", block_name(static_cast<Block>(b)));
    report += buf;
  }
  report += "\n";
  for (int t = 0; t < kNumTerms; ++t) {
    std::snprintf(buf, sizeof(buf), "%-12s", term_name(static_cast<Term>(t)));
    report += buf;
    for (int b = 0; b < kNumBlocks; ++b) {
      const double e = result.worst_error[t][b];
      if (e < 0) {
        std::snprintf(buf, sizeof(buf), " %11s", "-");
      } else {
        std::snprintf(buf, sizeof(buf), " %11.2e", e);
      }
      report += buf;
    }
    report += "\n";
  }
  result.report = report;
  return result;
}

GradientCheckResult CheckEnergyJacobian(const TrackerModel& model, const Linearization& lin,
                                        const EnergyOptions& energy_options, const Eigen::VectorXd& x,
                                        const GradientCheckOptions& options) {
  Eigen::VectorXd r;
  JacobianMatrix j;
  EvaluateResiduals(model, lin, energy_options, x, &r, &j);
  auto f = [&](const Eigen::VectorXd& at, Eigen::VectorXd* out) {
    EvaluateResiduals(model, lin, energy_options, at, out, nullptr);
  };
  return CompareWithFiniteDifferences(f, x, j, lin.layout, lin.term_rows, options);
}

}  // namespace face_reenact::tracker
