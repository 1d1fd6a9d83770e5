#pragma once
// The image formation model S(P) of the paper (Sec. 4, Eq. 1-4) as plain data, shared by the
// Vulkan renderer (renderer.h) and its CPU twin (cpu_renderer.h). docs/renderer.md is the spec.
//
// Conventions (both implementations follow them exactly):
// - Camera frame: computer-vision style, right-handed, x right, y down, z forward (the camera
//   looks down +z; visible points have z > 0). Units: metres.
// - Pose: X_cam = R v + t with R = Rz(rz) * Ry(ry) * Rx(rx) (rotate about the model's x axis
//   first, then y, then z; angles in radians). The model frame has +y up and +z out of the
//   face, so a face looking straight at the camera has rx = pi (see frontal_pose()).
// - Pinhole projection: u = fx * x / z + cx, v = fy * y / z + cy in pixels, where the CENTRE of
//   the top-left pixel is (0, 0) (OpenCV). Pixel (i, j) samples the scene at (u, v) = (i, j).
// - Lighting: Lambertian, 3-band real spherical harmonics of the camera-space unit normal,
//   per colour channel: colour_c = albedo_c * sum_k gamma[c * 9 + k] * y_k(n) (Eq. 3), per
//   vertex, then interpolated (Gouraud) across triangles.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <Eigen/LU>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace face_reenact {
struct FaceModel;
}

namespace face_reenact::gpu {

inline constexpr int kNumShBands = 3;
inline constexpr int kNumShCoefficients = 9;   // per colour channel
inline constexpr int kNumShParameters = 27;    // gamma: [channel * 9 + k], channel = R, G, B

// The 9 real SH basis functions of unit vector n = (x, y, z), orthonormal on the sphere:
//   y0 = 0.282095                      (1 / (2 sqrt(pi)))
//   y1 = 0.488603 y, y2 = 0.488603 z, y3 = 0.488603 x          (sqrt(3 / (4 pi)))
//   y4 = 1.092548 x y, y5 = 1.092548 y z, y7 = 1.092548 x z    (sqrt(15 / (4 pi)))
//   y6 = 0.315392 (3 z^2 - 1)                                    (sqrt(5 / (16 pi)))
//   y8 = 0.546274 (x^2 - y^2)                                    (sqrt(15 / (16 pi)))
// Evaluated in the camera frame (x right, y down, z forward).
std::array<float, kNumShCoefficients> sh_basis(const Eigen::Vector3f& n);

// Camera-space lighting coefficients for a uniform (ambient) light of RGB irradiance `rgb`:
// only the DC term, gamma[c * 9] = rgb[c] / y0.
std::array<float, kNumShParameters> ambient_sh(const Eigen::Vector3f& rgb);

// R = Rz(rz) * Ry(ry) * Rx(rx).
Eigen::Matrix3f rotation_from_euler(const Eigen::Vector3f& euler_xyz);

// The head's rotation relative to facing the camera, about the model axes, as an axis-angle
// vector in radians: R(euler) = Rx(pi) R_head. This is the pose the expression stream and the
// parameter files carry (docs/stream-protocol.md); zero for a frontal face.
Eigen::Vector3f head_rotation_axis_angle(const Eigen::Vector3f& euler_xyz);

// P = (alpha, beta, delta, gamma, R, t), Eq. 4.
struct FaceParameters {
  Eigen::VectorXf alpha;   // identity; may be shorter than the model's K_id (rest zero)
  Eigen::VectorXf beta;    // albedo; may be shorter than K_alb (rest zero)
  Eigen::VectorXf delta;   // expression; may be shorter than K_exp (rest zero)
  std::array<float, kNumShParameters> gamma{};  // SH lighting, gamma[channel * 9 + k]
  Eigen::Vector3f euler = Eigen::Vector3f::Zero();        // (rx, ry, rz), radians
  Eigen::Vector3f translation = Eigen::Vector3f::Zero();  // metres, camera frame

  // All values finite and each vector no longer than the model allows (pass -1 to skip a size).
  bool IsValid(std::string* why, int max_identity = -1, int max_expression = -1, int max_albedo = -1) const;
};

// Neutral parameters at `distance` metres in front of the camera, facing it (rx = pi), under a
// white ambient light of irradiance 1.
FaceParameters frontal_pose(float distance);

// How far the head at `params` is turned from facing the camera, in degrees (0..180): the angle
// between the face's forward axis and its ray to the camera.
float head_turn_from_camera_deg(const FaceParameters& params);

struct PinholeCamera {
  float fx = 525.0f;
  float fy = 525.0f;
  float cx = 319.5f;
  float cy = 239.5f;
  int width = 640;
  int height = 480;
  // Triangles with any vertex nearer than near_plane or farther than far_plane are dropped
  // whole (no clipping): a face never straddles these planes in use.
  float near_plane = 0.05f;
  float far_plane = 50.0f;

  bool IsValid(std::string* why) const;
  // The camera of pyramid level `level` (each level halves the resolution, rounding down): the
  // focal lengths halve and the principal point maps as c' = (c + 0.5) / 2 - 0.5, so that
  // pixel centres of the coarse level sit at the centres of 2x2 fine blocks.
  PinholeCamera Downsampled(int level) const;
};

// Bit (1 << FacePart) per model part to draw.
using PartMask = uint32_t;
inline constexpr PartMask kAllParts = 0x1FF;
// Face | Scalp | Ear | Neck: the skin the tracker fits.
inline constexpr PartMask kSkinParts = 0x0F;

struct RenderOptions {
  PartMask parts = kSkinParts;  // a triangle is drawn when all three vertices are in `parts`
  bool cull_back_faces = true;  // drop triangles that face away from the camera
  // Whether the CPU rasteriser interpolates GBuffer::normal. A caller that never reads the
  // normals (the tracker's synthesis on colour-only input, the tracked geometry the frame texture
  // looks up) saves every covered pixel a square root and three divisions, a fifth of its cost;
  // its buffer's normals are then zero. The other fields are the same bits either way.
  bool normals = true;
  // The same for GBuffer::color, for callers that read only the geometry (those whose vertex
  // states are not shaded, VertexColors::kNone, whose colours are zero anyway): left zero.
  bool colors = true;
  bool IsValid(std::string* why) const;
};

// A 3N x K model basis stored vertex-major (row-major): the 3 x K block of one vertex is
// contiguous. The hot readers go vertex by vertex (the tracker's per-pixel Jacobian rows and
// per-vertex evaluation, 3 vertices of a triangle at a time), and in column-major order each of
// those reads touched K cache lines 12N bytes apart. Whole-model products (y = E c) stream it
// either way; the GPU passes that want columns upload a column-major copy.
using BasisMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// A basis's nonzero entries vertex by vertex: for vertex v, the columns in [begin[v], begin[v+1])
// of `column` (ascending) whose x, y, z rows are not all zero, and those three values in `xyz`.
// The expression blendshapes are local: on the built model a vertex is moved by 10 of the 52 on
// average and a quarter of the vertices by none, so a vertex's sum over its own columns skips
// four fifths of the products and reads a quarter of the bytes (the dense basis is 3 MB at 4.8k
// vertices, beyond the cache; the CPU renderer and the tracker evaluate it every solver step).
struct VertexColumns {
  std::vector<int32_t> begin;   // N + 1
  std::vector<int32_t> column;  // one per nonzero vertex block
  std::vector<float> xyz;       // three per nonzero vertex block

  // Of a 3N x K basis of N vertices (a basis without columns may have no rows).
  static VertexColumns Of(const BasisMatrix& basis, int num_vertices);
  // Exactly `basis`'s nonzero blocks, every other entry of it zero, for N vertices.
  bool Describes(const BasisMatrix& basis, int num_vertices) const;

  // Vertex v's sum of weights[column] * (x, y, z) over its listed columns, in column order, in T
  // (the CPU renderer's float, the tracker's double).
  template <typename T, typename Weights>
  std::array<T, 3> Sum(int v, const Weights& weights) const {
    std::array<T, 3> s{T(0), T(0), T(0)};
    for (int32_t e = begin[static_cast<size_t>(v)]; e < begin[static_cast<size_t>(v) + 1]; ++e) {
      const T w = static_cast<T>(weights[column[static_cast<size_t>(e)]]);
      const float* b = &xyz[3 * static_cast<size_t>(e)];
      for (int c = 0; c < 3; ++c) s[static_cast<size_t>(c)] += static_cast<T>(b[c]) * w;
    }
    return s;
  }
};

// The linear model the renderer evaluates: a FaceModel's geometry and albedo, or any other
// mesh with the same structure (test geometry). Bases are 3N x K, interleaved xyz rows.
struct RenderModel {
  std::vector<std::array<int32_t, 3>> triangles;  // counter-clockwise seen from outside
  std::vector<uint8_t> vertex_part;               // N, FacePart values (0..31)
  Eigen::VectorXf mean_shape;                     // 3N, metres, model frame
  BasisMatrix identity_basis;                     // 3N x K_id
  BasisMatrix expression_basis;                   // 3N x K_exp
  Eigen::VectorXf mean_albedo;                    // 3N, linear RGB
  BasisMatrix albedo_basis;                       // 3N x K_alb
  // expression_basis's nonzeros by vertex: made by IndexExpression, after any change to the basis
  // (IsValid refuses a model where they disagree).
  VertexColumns expression_columns;

  int num_vertices() const { return static_cast<int>(vertex_part.size()); }
  int num_triangles() const { return static_cast<int>(triangles.size()); }
  void IndexExpression() { expression_columns = VertexColumns::Of(expression_basis, num_vertices()); }
  bool IsValid(std::string* why) const;
  static RenderModel FromFaceModel(const FaceModel& model);
};

// The per-pixel output of S(P) read back to the host. Pixel (i, j) is at index j * width + i.
// Uncovered pixels have triangle == -1 and zeros everywhere else.
struct GBuffer {
  int width = 0;
  int height = 0;
  std::vector<float> color;        // 3 per pixel: C_S, shaded linear RGB
  std::vector<float> position;     // 3 per pixel: X_S, camera space (m)
  std::vector<float> normal;       // 3 per pixel: N_S, unit, camera space
  std::vector<float> barycentric;  // 3 per pixel: perspective-correct, sum 1
  std::vector<int32_t> triangle;   // 1 per pixel: model triangle index, -1 = not covered
  std::vector<int32_t> vertices;   // 3 per pixel: the triangle's vertex indices (-1 if none)

  // What the last draw wrote into this buffer (the CPU rasteriser, or a GPU read-back of a box):
  // outside `i0..i1` x `j0..j1` (inclusive) every pixel is as Resize leaves it, so drawing into the
  // same buffer again clears only that rectangle (at 640x480 the whole buffer is 20 MB, and
  // clearing it cost as much as drawing the face). Valid only while `triangle` is the same
  // allocation it names; Resize forgets it. A caller that writes uncovered pixels in place must
  // call Resize first.
  struct DrawnTrace {
    const int32_t* triangle_data = nullptr;
    int i0 = 0, i1 = -1, j0 = 0, j1 = -1;
  } drawn;

  void Resize(int w, int h);
  // Whether the buffer is w x h in every channel and `drawn` names its current allocation: then
  // only that rectangle needs clearing before the next draw.
  bool DrawnIsKnown(int w, int h) const;
  // Sizes the buffer to w x h with every pixel as Resize leaves it, clearing only the rectangle of
  // the last draw where that is known (`drawn`, then forgotten until the caller's draw sets it).
  void ClearForDraw(int w, int h, int threads);
  bool covered(int i, int j) const { return triangle[static_cast<size_t>(j) * width + i] >= 0; }
  size_t covered_count() const;
  // Camera-space depth z of a pixel, 0 when not covered.
  float depth(int i, int j) const { return position[(static_cast<size_t>(j) * width + i) * 3 + 2]; }
};

// Pixels i0..i1 x j0..j1, inclusive.
struct PixelBox {
  int i0 = 0, i1 = -1, j0 = 0, j1 = -1;
  bool empty() const { return i1 < i0 || j1 < j0; }
};

struct VertexState;
// The pixels the triangles of `state` can cover in `camera`'s image, grown by `margin` and clipped
// to the image: the box of the projections of the vertices within the depth range (a triangle
// with a vertex outside it is not drawn). Empty when no vertex is in range or the box misses the image.
PixelBox ProjectedBox(const VertexState& state, const PinholeCamera& camera, int margin);

// Per-vertex results of the model and lighting stages (for tests and the tracker's CPU paths).
struct VertexState {
  Eigen::VectorXf model_positions;   // 3N, model frame: a_id + E_id alpha + E_exp delta
  Eigen::VectorXf albedo;            // 3N: a_alb + E_alb beta
  Eigen::VectorXf camera_positions;  // 3N: R v + t
  Eigen::VectorXf camera_normals;    // 3N: R n, n = normalised area-weighted sum of face normals
  Eigen::VectorXf colors;            // 3N: albedo * SH irradiance(camera normal)
};

}  // namespace face_reenact::gpu
