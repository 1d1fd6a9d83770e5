// Shared declarations of the image-formation shaders (docs/renderer.md): the per-frame block
// of pose and lighting, and (through sh_basis.glsl) the SH basis. Included by vertex_shade.comp.

// Per-frame pose and lighting, written by the host (renderer.cc: FrameBlock mirrors it).
struct FrameBlock {
  vec4 rotation_rows[3];  // R, row-major, xyz used
  vec4 translation;       // t, xyz used
  float gamma[27];        // SH lighting, gamma[channel * 9 + k]
};

#include "sh_basis.glsl"
