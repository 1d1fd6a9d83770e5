#pragma once
// Double-precision twins of core/gpu's rotation_from_euler and sh_basis (same conventions,
// same constants; tests/tracker checks them against the float originals) plus the derivatives
// the Jacobian needs. Double precision keeps the finite-difference checks meaningful.
#include <Eigen/Core>
#include <array>

namespace face_reenact::tracker::internal {

struct RotationWithDerivatives {
  Eigen::Matrix3d r;
  std::array<Eigen::Matrix3d, 3> d;  // dR / d(rx, ry, rz)
};

// R = Rz(rz) Ry(ry) Rx(rx) and its partial derivatives.
RotationWithDerivatives rotation_with_derivatives(const Eigen::Vector3d& euler);

inline constexpr double kSh0 = 0.282095, kSh1 = 0.488603, kSh2 = 1.092548, kSh3 = 0.315392, kSh4 = 0.546274;

// The 9 SH basis values at n (not necessarily unit: the polynomials are evaluated as is).
std::array<double, 9> sh_basis(const Eigen::Vector3d& n);
// Gradient of each basis polynomial with respect to n.
std::array<Eigen::Vector3d, 9> sh_basis_gradient(const Eigen::Vector3d& n);

}  // namespace face_reenact::tracker::internal
