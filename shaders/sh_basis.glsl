// The 9 real spherical-harmonics basis functions of the image-formation model (Eq. 3) and their
// gradients. One definition for the renderer (common.glsl) and the tracker (tracker_common.glsl);
// the host twins are gpu::sh_basis (image_formation.h) and tracker's internal::sh_basis.
#ifndef FR_SH_BASIS_GLSL
#define FR_SH_BASIS_GLSL

const float kSh0 = 0.282095, kSh1 = 0.488603, kSh2 = 1.092548, kSh3 = 0.315392, kSh4 = 0.546274;

void sh_basis(vec3 n, out float y[9]) {
  y[0] = kSh0;
  y[1] = kSh1 * n.y;
  y[2] = kSh1 * n.z;
  y[3] = kSh1 * n.x;
  y[4] = kSh2 * n.x * n.y;
  y[5] = kSh2 * n.y * n.z;
  y[6] = kSh3 * (3.0 * n.z * n.z - 1.0);
  y[7] = kSh2 * n.x * n.z;
  y[8] = kSh4 * (n.x * n.x - n.y * n.y);
}

// Gradient of each basis polynomial with respect to n (n not renormalised).
void sh_basis_gradient(vec3 n, out vec3 g[9]) {
  g[0] = vec3(0.0);
  g[1] = vec3(0.0, kSh1, 0.0);
  g[2] = vec3(0.0, 0.0, kSh1);
  g[3] = vec3(kSh1, 0.0, 0.0);
  g[4] = vec3(kSh2 * n.y, kSh2 * n.x, 0.0);
  g[5] = vec3(0.0, kSh2 * n.z, kSh2 * n.y);
  g[6] = vec3(0.0, 0.0, 6.0 * kSh3 * n.z);
  g[7] = vec3(kSh2 * n.z, 0.0, kSh2 * n.x);
  g[8] = vec3(2.0 * kSh4 * n.x, -2.0 * kSh4 * n.y, 0.0);
}

#endif  // FR_SH_BASIS_GLSL
