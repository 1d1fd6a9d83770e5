#pragma once
// The statistics behind the identity model: rigid alignment of sampled shapes (Procrustes
// without scale, since the tracker estimates the head pose itself) and PCA of the aligned
// samples through the eigen-decomposition of their Gram matrix.
#include <Eigen/Core>
#include <cstdint>
#include <string>

namespace face_reenact {

// Points are stored interleaved in a 3N vector (x0 y0 z0 x1 ...).
struct RigidTransform {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
};

// The rotation R (det +1) and translation t minimising sum_i w_i |R x_i + t - y_i|^2 (Kabsch).
// `weights` may be empty (all 1). Throws Error on size mismatch or zero total weight.
RigidTransform fit_rigid(const Eigen::VectorXf& x, const Eigen::VectorXf& y,
                         const Eigen::VectorXf& weights = Eigen::VectorXf());
// Applies R x + t to every point of a 3N vector.
void apply_rigid(const RigidTransform& t, Eigen::Ref<Eigen::VectorXf> points);

// Generalised Procrustes on the columns of `samples` (3N x S, modified in place): aligns every
// sample rigidly to the running mean until the mean moves less than `tolerance` (RMS, same units)
// or `max_iterations` pass. The first mean is the column average. Returns the final mean.
struct ProcrustesSummary {
  int iterations = 0;
  double final_mean_change = 0;  // RMS per point of the last update
  double mean_residual = 0;      // RMS distance of the aligned samples to the mean
};
Eigen::VectorXf align_samples(Eigen::MatrixXf* samples, const Eigen::VectorXf& weights, int max_iterations,
                              double tolerance, ProcrustesSummary* summary);

// Share of the variance of a linear shape model, over the weighted points, that is rigid motion
// of those points: sum_k sigma_k^2 |P e_k|_w^2 / sum_k sigma_k^2 |e_k|_w^2, P projecting onto
// the six infinitesimal rigid motions (three translations, three rotations about the weighted
// centroid) of `mean`. A basis aligned by Procrustes on the same weights has (nearly) none: its
// components cannot stand in for the pose. `basis` is 3N x K, `sigma` K, `weights` N (empty: all
// 1). Returns 0 for a model with no variance over the weighted points; throws Error on size
// mismatch or zero total weight.
double rigid_motion_share(const Eigen::VectorXf& mean, const Eigen::MatrixXf& basis, const Eigen::VectorXf& sigma,
                          const Eigen::VectorXf& weights = Eigen::VectorXf());

struct PcaOptions {
  int min_components = 80;
  int max_components = 160;
  double variance_target = 0.995;  // keep max(min_components, #components reaching this)
  // Above this many samples the top of the Gram spectrum is found by randomised subspace
  // iteration instead of a full dense eigen-decomposition (O(S^3)), which would dominate the
  // build time for thousands of samples.
  int dense_limit = 1200;
  int subspace_size = 640;   // block size of the subspace iteration (>= max_components)
  int subspace_iterations = 4;
  uint64_t seed = 1;

  bool IsValid(std::string* why) const;
};

struct PcaResult {
  Eigen::MatrixXf basis;          // D x K, orthonormal columns
  Eigen::VectorXf sigma;          // K, standard deviation of each coefficient, sorted decreasing
  double explained_variance = 0;  // sum of kept variances / total variance
  double total_variance = 0;      // sum over all directions (trace of the sample covariance)
  Eigen::VectorXd spectrum;       // variances of all computed components, decreasing
  int components_for_target = 0;  // #components reaching variance_target (of those computed)
  bool dense = true;              // which eigen-solver path was taken
};

// PCA of zero-mean samples (D x S, columns are samples; the caller subtracts the mean).
// Components with (numerically) zero variance are never kept. Throws Error when there are
// fewer than 2 samples or no variance at all.
PcaResult pca_of_centered_samples(const Eigen::MatrixXf& centered, const PcaOptions& options);

}  // namespace face_reenact
