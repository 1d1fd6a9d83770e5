// Shared declarations of the tracker's compute passes (docs/tracker.md, "Vulkan solver").
// Everything here mirrors core/tracker/src/energy.cc and math_internal.cc in float.

// Per-linearisation constants written by the host (vulkan_solver.cc: TrackParams mirrors it).
struct TrackParams {
  uint num_pixels;       // P pixel items (8 rows each: 3 point, 2 plane, 3 colour)
  uint num_landmarks;    // L landmark items (2 rows each)
  uint num_regularizer;  // R regulariser rows
  uint n;                // unknowns (columns of J)
  uint k_id, k_alb, k_exp;                   // solved coefficients per block
  uint o_id, o_alb, o_exp, o_gam, o_rot, o_t;  // column offsets of the blocks
  uint model_id, model_alb, model_exp;       // the model's full coefficient counts
  uint num_vertices;
  uint width;              // of the pyramid level (pixel index = j * width + i)
  uint regularize_shared;  // identity/albedo prior rows present
  uint rows;               // column stride of the column-major J: (8 P + 2 L + R) rounded up to 4
  float s_point, s_plane, s_col, s_lan, s_reg;  // residual pre-scales (energy.cc)
  float fx, fy, cx, cy;
  float s_reg_exp;  // expression prior rows: sqrt(w_reg_expression) / sigma_exp
  float r0[9];  // rotation at the linearisation point, row-major (freezes model normals)
  float w_sparse_exp;    // EnergyOptions::w_expression_sparsity (0 = off)
  float sparse_eps_exp;  // EnergyOptions::expression_sparsity_epsilon
  float pad1, pad2;
};

// The level's input per pixel (vulkan_solver.cc, prepare_level): point (w = valid depth), normal
// (w = exists), colour, and the colour's gradient along u and along v (EnergyOptions::
// color_follows_projection; zero when off).
const uint kInputVec4sPerPixel = 5u;

// A pixel that carries at least one term (written by tracker_classify.comp).
const uint kPixelItemWords = 9;  // pixel, flags, v0, v1, v2, b0, b1, b2, colour weight
const uint kFlagPoint = 1u, kFlagPlane = 2u, kFlagColor = 4u;
const uint kRowsPerPixel = 8u;

// The largest number of unknowns the GPU passes support (one PCG element per invocation of a
// 256-invocation workgroup).
const uint kMaxUnknowns = 255u;

// A push constant size of kSizeFromParams: the pass takes it from the TrackParams of its level,
// which the device-driven loop's counts stage writes (tracker_loop.comp), since the host that
// records the frame's whole schedule ahead does not know the counts.
const uint kSizeFromParams = 0xffffffffu;
// Rows of the system (zero rows included): 8 per pixel item, 2 per landmark, then the prior.
uint system_rows(uint pixels, uint landmarks, uint regularizer) { return kRowsPerPixel * pixels + 2u * landmarks + regularizer; }
// Rows per workgroup of tracker_jt.comp and tracker_jtj.comp (vulkan_solver.cc: kJtChunk, kJtjRowsPerChunk).
const uint kJtChunkRows = 256u;
const uint kJtjChunkRows = 1024u;
// tracker_jtj.comp: [J | r]'s n + 1 columns in tiles of kJtjTile, one invocation per pair of tiles
// (the upper triangle), kJtjPairsPerGroup pairs per workgroup (vulkan_solver.cc: the same names).
const uint kJtjTile = 8u;
const uint kJtjPairsPerGroup = 64u;
uint jtj_tiles(uint n) { return (n + kJtjTile) / kJtjTile; }
uint jtj_pair_groups(uint n) {
  const uint t = jtj_tiles(n);
  return (t * (t + 1u) / 2u + kJtjPairsPerGroup - 1u) / kJtjPairsPerGroup;
}

mat3 rows3(vec3 a, vec3 b, vec3 c) { return transpose(mat3(a, b, c)); }

// R = Rz(rz) Ry(ry) Rx(rx) and dR / d(rx, ry, rz) (math_internal.cc).
void rotation_with_derivatives(vec3 e, out mat3 r, out mat3 d[3]) {
  const float cx = cos(e.x), sx = sin(e.x), cy = cos(e.y), sy = sin(e.y), cz = cos(e.z), sz = sin(e.z);
  const mat3 rx = rows3(vec3(1, 0, 0), vec3(0, cx, -sx), vec3(0, sx, cx));
  const mat3 ry = rows3(vec3(cy, 0, sy), vec3(0, 1, 0), vec3(-sy, 0, cy));
  const mat3 rz = rows3(vec3(cz, -sz, 0), vec3(sz, cz, 0), vec3(0, 0, 1));
  const mat3 drx = rows3(vec3(0, 0, 0), vec3(0, -sx, -cx), vec3(0, cx, -sx));
  const mat3 dry = rows3(vec3(-sy, 0, cy), vec3(0, 0, 0), vec3(-cy, 0, -sy));
  const mat3 drz = rows3(vec3(-sz, -cz, 0), vec3(cz, -sz, 0), vec3(0, 0, 0));
  r = rz * ry * rx;
  d[0] = rz * ry * drx;
  d[1] = rz * dry * rx;
  d[2] = drz * ry * rx;
}

#include "sh_basis.glsl"
