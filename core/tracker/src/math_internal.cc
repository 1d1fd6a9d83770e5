#include "math_internal.h"

#include <cmath>

namespace face_reenact::tracker::internal {

RotationWithDerivatives rotation_with_derivatives(const Eigen::Vector3d& e) {
  const double cx = std::cos(e.x()), sx = std::sin(e.x());
  const double cy = std::cos(e.y()), sy = std::sin(e.y());
  const double cz = std::cos(e.z()), sz = std::sin(e.z());
  Eigen::Matrix3d rx, ry, rz, drx, dry, drz;
  rx << 1, 0, 0, 0, cx, -sx, 0, sx, cx;
  ry << cy, 0, sy, 0, 1, 0, -sy, 0, cy;
  rz << cz, -sz, 0, sz, cz, 0, 0, 0, 1;
  drx << 0, 0, 0, 0, -sx, -cx, 0, cx, -sx;
  dry << -sy, 0, cy, 0, 0, 0, -cy, 0, -sy;
  drz << -sz, -cz, 0, cz, -sz, 0, 0, 0, 0;
  RotationWithDerivatives out;
  out.r = rz * ry * rx;
  out.d[0] = rz * ry * drx;
  out.d[1] = rz * dry * rx;
  out.d[2] = drz * ry * rx;
  return out;
}

std::array<double, 9> sh_basis(const Eigen::Vector3d& n) {
  const double x = n.x(), y = n.y(), z = n.z();
  return {kSh0, kSh1 * y, kSh1 * z, kSh1 * x, kSh2 * x * y, kSh2 * y * z, kSh3 * (3 * z * z - 1), kSh2 * x * z,
          kSh4 * (x * x - y * y)};
}

std::array<Eigen::Vector3d, 9> sh_basis_gradient(const Eigen::Vector3d& n) {
  const double x = n.x(), y = n.y(), z = n.z();
  return {Eigen::Vector3d(0, 0, 0),
          Eigen::Vector3d(0, kSh1, 0),
          Eigen::Vector3d(0, 0, kSh1),
          Eigen::Vector3d(kSh1, 0, 0),
          Eigen::Vector3d(kSh2 * y, kSh2 * x, 0),
          Eigen::Vector3d(0, kSh2 * z, kSh2 * y),
          Eigen::Vector3d(0, 0, 6 * kSh3 * z),
          Eigen::Vector3d(kSh2 * z, 0, kSh2 * x),
          Eigen::Vector3d(2 * kSh4 * x, -2 * kSh4 * y, 0)};
}

}  // namespace face_reenact::tracker::internal
