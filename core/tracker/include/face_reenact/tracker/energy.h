#pragma once
// The tracking energy of Sec. 5 (Eq. 5-11) and its analytic Jacobian (Sec. 6).
//
//   E = w_point E_point + w_plane E_plane + w_col E_col + w_lan E_lan + w_reg E_reg
//
// Units and normalisation (docs/tracker.md): the paper's weights are used as given, with
//  - geometric distances (E_point, E_plane) in units of `geometry_unit_m` (default 1 cm),
//  - colours as linear RGB in [0, 1],
//  - landmark offsets in pixels of an image `landmark_reference_width` (640) pixels wide, so the
//    term means the same on every pyramid level,
//  - dense terms averaged over the pixels that carry them and E_lan over the confidence-weighted
//    landmark count, so the balance does not depend on resolution; E_reg is summed (Eq. 11).
// Each residual r_i is stored pre-weighted so that E = sum r_i^2.
//
// Linearisation (what stays fixed within one Gauss-Newton step): the pixel correspondences of
// the rendered G-buffer (triangle, vertices, barycentrics), which pixels and landmarks carry
// which term, and the model-frame vertex normals. Normals are therefore treated as constant
// with respect to shape (alpha, delta) inside one step, as many implementations do; they do
// rotate with the pose, and that derivative is exact. Within these rules the Jacobian below is
// the exact derivative of the residual function, which the gradient checker verifies.
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/parameter_layout.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker {

// What the tracker draws of the model: every part a camera sees (skin, eyeballs, teeth and
// tongue), z-buffered. Skin alone leaves holes where the eyeballs are: there the rendered
// surface is the eye socket about 2 cm behind the eye the camera measures, close enough to be
// kept as a correspondence, and those few pixels outweighed all the others: a calibration
// started at the true parameters slid 4 mm nearer (docs/tracker.md, "What is drawn").
inline constexpr gpu::RenderOptions kTrackedParts{gpu::kAllParts, true};

// EnergyOptions::color_parts' default: every part but the scalp, ears and neck.
inline constexpr gpu::PartMask kColorParts =
    gpu::kAllParts & ~((1u << static_cast<int>(FacePart::Scalp)) | (1u << static_cast<int>(FacePart::Ear)) |
                       (1u << static_cast<int>(FacePart::Neck)));

enum class Term { kPoint = 0, kPlane, kColor, kLandmark, kRegularizer };
inline constexpr int kNumTerms = 5;
const char* term_name(Term t);

// Weighted term values (each already multiplied by its weight); total() is E.
struct TermEnergies {
  std::array<double, kNumTerms> value{};
  double operator[](Term t) const { return value[static_cast<int>(t)]; }
  double total() const;
};

struct EnergyOptions {
  bool use_point = true;
  bool use_plane = true;
  bool use_color = true;
  bool use_landmarks = true;
  bool use_regularizer = true;
  double w_point = 2.0;
  double w_plane = 10.0;
  double w_col = 20.0;
  double w_lan = 0.125;
  double w_reg = 0.025;             // identity and albedo rows of E_reg (Eq. 11: alpha, beta)
  double w_reg_expression = 0.025;  // expression rows of E_reg (Eq. 11: delta)
  // A sparsity (L1) prior on the blendshape weights, added to the expression rows of E_reg:
  // w_expression_sparsity * sum_i |delta_i|, minimised as iteratively reweighted least squares
  // (each row's weight is frozen at the linearisation point: w / (|delta_i| + epsilon)). The 52
  // ARKit blendshapes hold near-cancelling combinations (jawOpen + mouthClose is a closed mouth),
  // which a quadratic prior leaves spread over many small weights; L1 prefers the fewest.
  // 0 = off (the paper's Eq. 11 only). docs/tracker.md, "Expression prior".
  double w_expression_sparsity = 0.0;
  double expression_sparsity_epsilon = 0.05;

  // E_col's derivative through the projection Pi (Sec. 5.3, "Analytical Partial Derivatives"):
  // the input colour a pixel is compared with is read where the pixel's surface point projects,
  // C_I(p) + grad C_I(p) (Pi(X_S) - p), so a motion of the face that moves its colours against
  // the image's has a derivative. Without it the correspondences are held in the image too and
  // E_col sees the geometry only through the shading of the normals. On frames with depth only:
  // without depth the face's distance is barely observed, and on RGB-only input with dlib's
  // landmarks the term moved it further off (docs/tracker.md, "Colour through the projection").
  bool color_follows_projection = true;
  // The parts E_col covers (a pixel counts when its triangle's three vertices are in them): the
  // face, eyes, teeth and tongue, whose colour the albedo model describes. The paper's model is a
  // face mask; the scalp is under hair on most people, the ears often too, the neck under a
  // collar or in the chin's shadow, and the model paints all three as skin. The geometric terms
  // still fit every part drawn (docs/tracker.md, "Colour through the projection").
  gpu::PartMask color_parts = kColorParts;
  // Robust colour read through the projection (Huber, as iteratively reweighted least squares):
  // a pixel whose rendered colour differs from the input by more than this (linear RGB,
  // Euclidean) at the linearisation point counts with weight threshold / difference, frozen for
  // the step like the L1 prior's weights. Faces carry colour the model's albedo cannot: brows,
  // lips, stubble, make-up, highlights, a hand or glasses in front; read through the projection,
  // a colour that cannot be matched would pull the geometry towards aligning it anyway. Applies
  // where color_follows_projection does; 0 = plain least squares (docs/tracker.md, "Colour
  // through the projection").
  double color_robust_threshold = 0.02;

  double geometry_unit_m = 0.01;            // E_point/E_plane distances are in these units
  double landmark_reference_width = 640.0;  // landmark offsets in pixels of an image this wide
  // Correspondence pruning (per linearisation): a pixel carries the geometric terms only when
  // |X_S - X_I| <= max_point_distance_m and N_S . N_I >= min_normal_dot (the plane terms also
  // need N_I).
  double max_point_distance_m = 0.05;
  double min_normal_dot = 0.2;
  float max_depth_jump_m = 0.02f;  // input normals are not taken across larger jumps
  bool inner_landmarks_only = true;  // the paper's 38 inner points (no jaw line, no brows)
  // All 38 inner points. By default the 12 eye points (iBUG 36-47) and the nose base (33) are
  // left out: their model vertices (eyelid margins, the underside of the nose) do not match
  // where dlib puts them. dlib does not follow a closing eyelid (a scripted second of closed
  // eyes read eyeBlink 0.00 with the eye points as without) and its eye points pulled the pose
  // (that recording: rotation 0.60 -> 1.24 degrees); with 33, seed 9001 tracked with dlib went
  // from 1.87 to 2.74 degrees. With exact landmarks (a recording's stored ones) all 38 read
  // blinks (0.005 -> 0.5) and lower most errors (docs/tracker.md, "Landmark visibility"), so
  // `track --all-inner-landmarks` can switch them on.
  bool all_inner_landmarks = false;
  // The four eye corners (iBUG 36, 39, 42, 45) even without all_inner_landmarks, on frames
  // without depth: where the lids meet, a closing lid does not move them and dlib places them
  // well on real faces. On video nothing else holds the eyes (the colour term barely sees an eye
  // at the tracking levels), and the fitted eyes sat half an eye's height off the real ones (eye
  // points' NME 0.038-0.057 of the eye distance on six clips, 0.015-0.020 with the corners; d10,
  // filmed from below, had the model's lower lids on her cheek), so eyes the output moves sampled
  // lids and lashes as eyeball. With depth the surface holds the face, and on the synthetic RGB-D
  // actors dlib's corners (0.045 eye distances off the true ones on those renders) moved the eyes
  // off: the demo's source read a blink its eyes never made. docs/tracker.md, "The eye corners".
  bool eye_corner_landmarks = true;
  // The brows (iBUG 17-26) too, beside the inner points: the brow blendshapes (browDown,
  // browInnerUp, browOuterUp) are then read from where the detector puts the brows, which on RGB
  // video is the only evidence of them (the colour barely changes as a brow lifts). Off in the
  // tracker (the paper's 38 points); the photo fit (photo_fit.h) takes them (docs/tracking-pipeline.md,
  // "A yardstick on real photos").
  bool use_brow_landmarks = false;
  // Landmark visibility: a landmark counts when its vertex is in front of the camera and the
  // render, at the pixel the vertex projects to, shows no surface more than this much nearer
  // (an uncovered pixel or one outside the image keeps it: the vertex is on the silhouette).
  // A depth test, not the vertex normal: the eyelid-margin vertices the eye landmarks sit on
  // (and the subnasale, 33) have normals that point away from the camera (the inner lid's
  // faces outweigh the outer ones), so a normal test never used them (docs/tracker.md,
  // "Landmark visibility").
  double landmark_occlusion_m = 0.01;
  // Which of the rendered pixels carry the dense terms (E_point, E_plane, E_col): 1 = every one
  // (the paper), 2 = every other one, in a checkerboard ((i + j) even on the level), 4 = every
  // fourth, on the lattice (i + 2j) divisible by 4 (every fourth pixel of a row, the next row's
  // shifted by two). The dense terms are normalised by their pixel counts, so a fraction of the
  // pixels keeps each term's weight against the landmarks and the prior; the linearisation, J and
  // every PCG product cost that fraction.
  // A face at the tracking levels covers thousands of pixels whose colours and depths change
  // smoothly, so a checkerboard of them constrains the 85 per-frame unknowns as well as all of
  // them do: the per-frame solves and the calibration take 2 (FaceTracker), the calibration 4
  // where the face is large on its level (TrackerOptions::calibration_sparse_face_width_px;
  // docs/real-time.md, "Every other pixel").
  int pixel_sampling = 1;

  bool IsValid(std::string* why) const;
};

// EnergyOptions::pixel_sampling's rule: whether pixel (i, j) of a level may carry the dense terms.
inline bool SampledPixel(int pixel_sampling, int i, int j) {
  return pixel_sampling == 1 || (pixel_sampling == 2 ? ((i + j) & 1) == 0 : ((i + 2 * j) & 3) == 0);
}

// The inner points EnergyOptions::all_inner_landmarks adds: the eyes (iBUG 36-47) and 33.
inline bool LeftOutUnlessAllInner(int ibug_index) { return ibug_index == 33 || (ibug_index >= 36 && ibug_index <= 47); }
// The eye corners (iBUG 36, 39, 42, 45): EnergyOptions::eye_corner_landmarks.
inline bool IsEyeCorner(int ibug_index) { return ibug_index == 36 || ibug_index == 39 || ibug_index == 42 || ibug_index == 45; }
inline bool IsBrowLandmark(int ibug_index) { return ibug_index >= 17 && ibug_index <= 26; }

// The model vertex E_lan matches an input landmark to: its own (InputLandmark::model_vertex) or
// the model's binding for its point; -1 when that is not a vertex of a model of `num_vertices`.
inline int LandmarkVertex(const InputLandmark& in, int bound_vertex, int num_vertices) {
  const int v = in.model_vertex >= 0 ? in.model_vertex : bound_vertex;
  return v >= 0 && v < num_vertices ? v : -1;
}

// Whether E_lan takes the model landmark `l` under `options` on a frame with or without depth
// (before its visibility test): the one rule for the CPU linearisation and the Vulkan solver.
inline bool EnergyUsesLandmark(const EnergyOptions& options, int ibug_index, uint8_t flags, bool frame_has_depth) {
  const bool inner = (flags & kLandmarkInner) != 0;
  if (options.inner_landmarks_only && !inner && !(options.use_brow_landmarks && IsBrowLandmark(ibug_index))) return false;
  if (!options.all_inner_landmarks && LeftOutUnlessAllInner(ibug_index) &&
      !(options.eye_corner_landmarks && !frame_has_depth && IsEyeCorner(ibug_index)))
    return false;
  return true;
}

// EnergyOptions::landmark_occlusion_m's rule for one landmark vertex at camera position x.
bool LandmarkVertexVisible(const Eigen::Vector3f& x, const gpu::GBuffer& gbuffer, const gpu::PinholeCamera& camera,
                           float occlusion_m);

// Whether E_col of `frame` is read through the projection (EnergyOptions::color_follows_projection:
// on frames with depth).
bool ColorFollowsProjection(const EnergyOptions& options, const InputFrame& frame);

// Whether the depth terms (E_point, E_plane) take part for `frame`: the only readers of the
// synthesis' positions beyond depth and of its normals.
bool UsesDepthTerms(const EnergyOptions& options, const InputFrame& frame);

// EnergyOptions::color_robust_threshold's weight of pixel `pixel`: 1 while the rendered colour
// (gbuffer.color) is within `threshold` of the input colour, threshold / difference beyond.
double RobustColorWeight(const gpu::GBuffer& gbuffer, size_t pixel, const Eigen::Vector3d& input_color, double threshold);

// One pixel that is valid in both the synthetic and the input image.
struct PixelSample {
  int32_t i = 0, j = 0;
  std::array<int32_t, 3> vertex{};
  std::array<double, 3> bary{};
  Eigen::Vector3d input_color = Eigen::Vector3d::Zero();
  // d C_I / d(u, v) at the pixel (zero unless EnergyOptions::color_follows_projection).
  Eigen::Matrix<double, 3, 2> input_color_gradient = Eigen::Matrix<double, 3, 2>::Zero();
  Eigen::Vector3d input_point = Eigen::Vector3d::Zero();
  Eigen::Vector3d input_normal = Eigen::Vector3d::Zero();
  bool point = false;  // carries E_point (3 residuals)
  bool plane = false;  // carries E_plane (2 residuals)
  bool color = false;  // carries E_col (3 residuals)
  double color_weight = 1.0;  // EnergyOptions::color_robust_threshold's weight of the colour rows
};

struct LandmarkSample {
  int32_t vertex = 0;
  Eigen::Vector2d target = Eigen::Vector2d::Zero();  // pixels of the level
  double confidence = 1.0;
};

// The per-vertex parts of the model that depend on the identity alone: its shape (mean + E_id
// alpha) and its albedo (mean + E_alb beta), in double, for the alpha and beta they were computed
// from (the model's full coefficient vectors). With them a vertex's position costs the 52
// expression columns instead of all 132 basis columns. A tracking solve keeps one per identity;
// a calibration's frames share one identity, and one set made for the step's coefficients serves
// all of them (each frame's evaluation made its own, vertex by vertex).
struct FixedModelParts {
  Eigen::VectorXd alpha, beta;
  std::vector<Eigen::Vector3d> shape, albedo;
};
// Vertices are split over up to `threads` threads (the same values for any count).
FixedModelParts ComputeFixedModelParts(const TrackerModel& model, const gpu::FaceParameters& params, int threads = 1);

// Everything held fixed while one Gauss-Newton step is solved.
struct Linearization {
  ParameterLayout layout;
  gpu::FaceParameters base;     // parameters at the linearisation point (supplies fixed blocks)
  gpu::PinholeCamera camera;    // of the pyramid level
  bool color_follows_projection = false;  // ColorFollowsProjection for this frame and options
  std::vector<PixelSample> pixels;
  std::vector<LandmarkSample> landmarks;
  Eigen::VectorXd model_normals;  // 3N, model frame, unit (frozen for this step)
  // Counts that normalise the dense terms, and the confidence sum of the landmarks.
  int num_point = 0, num_plane = 0, num_color = 0;
  double landmark_weight_sum = 0;
  int num_regularizer = 0;
  // False for all but one frame of a multi-frame calibration, so the shared identity/albedo
  // prior is counted once: then only the expression prior has rows here.
  bool regularize_shared = true;
  // First row of each term in r / J; term_rows[kNumTerms] is the number of residuals.
  std::array<Eigen::Index, kNumTerms + 1> term_rows{};
  // Optional (the solver sets it; Linearize does not): used by EvaluateResiduals where its
  // alpha / beta are those it evaluates at (the base's for a block the layout does not solve, x's
  // for one it does). Results are bit-identical with and without it.
  std::shared_ptr<const FixedModelParts> fixed;

  Eigen::Index num_residuals() const { return term_rows[kNumTerms]; }
};

// The parts for the identity and albedo that EvaluateResiduals(model, lin, ..., x) evaluates at
// (x's where the layout solves them): the frames of a calibration, which share them, take one set.
// `kept` itself where it was made for those very coefficients (a step accepted at its trial x
// is linearised at the same x), else new ones.
std::shared_ptr<const FixedModelParts> FixedModelPartsAt(const TrackerModel& model, const Linearization& lin,
                                                         const Eigen::VectorXd& x,
                                                         std::shared_ptr<const FixedModelParts> kept = nullptr,
                                                         int threads = 1);

// E_reg's rows for a layout: identity and albedo (unless another frame of a joint solve carries
// them: Linearization::regularize_shared false), then the expression.
inline int RegularizerRows(const ParameterLayout& layout, bool regularize_shared) {
  return (regularize_shared ? layout.num_identity + layout.num_albedo : 0) + layout.num_expression;
}

// Builds the linearisation at parameters `params` from their render (`state` from
// CpuRenderer::evaluate or the GPU twin, `gbuffer` rendered with `level_frame.camera`).
Linearization Linearize(const TrackerModel& model, const ParameterLayout& layout, const gpu::FaceParameters& params,
                        const gpu::VertexState& state, const gpu::GBuffer& gbuffer, const InputFrame& level_frame,
                        const EnergyOptions& options, bool regularize_shared = true);

// J is stored in single precision, as the paper's GPU solver stores it: the PCG products read
// it several times per Gauss-Newton iteration and are bound by memory bandwidth, so half the
// bytes is half their time. Every entry is computed in double and rounded once (relative error
// 6e-8, far below the linearisation's own); the products accumulate in double (pcg.h).
using JacobianMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// r(x) and, when `jacobian` is not null, J = dr/dx (num_residuals x layout.num_parameters()).
// `energies` (optional) receives the weighted value of each term. The pixel rows are split over
// up to `threads` threads (large linearisations only); r and J are bit-identical for any count.
void EvaluateResiduals(const TrackerModel& model, const Linearization& lin, const EnergyOptions& options,
                       const Eigen::VectorXd& x, Eigen::VectorXd* residuals, JacobianMatrix* jacobian,
                       TermEnergies* energies = nullptr, int threads = 1);

}  // namespace face_reenact::tracker
