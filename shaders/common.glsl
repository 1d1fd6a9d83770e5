// Shared declarations of the image-formation shaders (docs/renderer.md). Included by
// model_eval.comp, vertex_shade.comp and gbuffer.vert.

// Per-frame pose and lighting, written by the host (renderer.cc: FrameBlock mirrors it).
struct FrameBlock {
  vec4 rotation_rows[3];  // R, row-major, xyz used
  vec4 translation;       // t, xyz used
  float gamma[27];        // SH lighting, gamma[channel * 9 + k]
};

// The 9 real SH basis functions (image_formation.h: sh_basis).
void sh_basis(vec3 n, out float y[9]) {
  y[0] = 0.282095;
  y[1] = 0.488603 * n.y;
  y[2] = 0.488603 * n.z;
  y[3] = 0.488603 * n.x;
  y[4] = 1.092548 * n.x * n.y;
  y[5] = 1.092548 * n.y * n.z;
  y[6] = 0.315392 * (3.0 * n.z * n.z - 1.0);
  y[7] = 1.092548 * n.x * n.z;
  y[8] = 0.546274 * (n.x * n.x - n.y * n.y);
}
