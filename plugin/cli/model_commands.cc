// `face-reenact model info` and `face-reenact model export`: look inside a face model and
// write any face of it as a mesh. (`model build` lives in model_build_commands.cc.)
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <random>

#include "command_registry.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/model/mesh_export.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/model/shape_statistics.h"

namespace face_reenact::cli {
namespace {

struct LoadedModel {
  FaceModel model;
  std::string path;
  double load_ms = 0;
};

LoadedModel load(const std::string& explicit_path) {
  LoadedModel l;
  l.path = resolve_model_path(explicit_path);
  auto t0 = std::chrono::steady_clock::now();
  l.model = load_face_model(l.path);
  l.load_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return l;
}

// Distance between the centroids of the two eyeball parts of the mean face, in metres.
double eye_centre_distance(const FaceModel& m) {
  Eigen::Vector3d c[2] = {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
  int count[2] = {0, 0};
  for (int v = 0; v < m.num_vertices(); ++v) {
    int side = m.vertex_part[v] == FacePart::LeftEye ? 0 : m.vertex_part[v] == FacePart::RightEye ? 1 : -1;
    if (side < 0) continue;
    c[side] += m.mean_shape.segment<3>(3 * v).cast<double>();
    ++count[side];
  }
  if (!count[0] || !count[1]) return 0;
  return (c[0] / count[0] - c[1] / count[1]).norm();
}

nlohmann::json describe(const LoadedModel& l) {
  const FaceModel& m = l.model;
  std::map<std::string, int> parts;
  for (auto p : m.vertex_part) ++parts[face_part_name(p)];
  Eigen::Map<const Eigen::Matrix<float, 3, Eigen::Dynamic>> pts(m.mean_shape.data(), 3, m.num_vertices());
  Eigen::Vector3f lo = pts.rowwise().minCoeff(), hi = pts.rowwise().maxCoeff();
  nlohmann::json landmarks = nlohmann::json::array();
  int silhouette = 0, inner = 0;
  for (const auto& lm : m.landmarks) {
    landmarks.push_back({{"ibug", lm.ibug_index},
                         {"vertex", lm.vertex},
                         {"silhouette", bool(lm.flags & kLandmarkSilhouette)},
                         {"inner", bool(lm.flags & kLandmarkInner)}});
    silhouette += bool(lm.flags & kLandmarkSilhouette);
    inner += bool(lm.flags & kLandmarkInner);
  }
  std::vector<float> sigma(m.identity_sigma.data(), m.identity_sigma.data() + m.identity_sigma.size());
  // How much of the identity variance over the face region is rigid motion, i.e. could stand in
  // for the head pose the tracker estimates (none when the builder aligned on the face region).
  const double rigid_share =
      rigid_motion_share(m.mean_shape, m.identity_basis, m.identity_sigma, m.part_weights(FacePart::Face));
  std::vector<float> asigma(m.albedo_sigma.data(), m.albedo_sigma.data() + m.albedo_sigma.size());
  return {{"file", l.path},
          {"file_bytes", std::filesystem::file_size(l.path)},
          {"load_ms", l.load_ms},
          {"format_version", kFaceModelFormatVersion},
          {"units", m.units},
          {"source", m.source},
          {"source_sha256", m.source_sha256},
          {"vertices", m.num_vertices()},
          {"triangles", m.num_triangles()},
          {"parts", parts},
          {"identity_components", m.num_identity()},
          {"identity_explained_variance", m.identity_explained_variance},
          {"identity_samples", m.identity_samples},
          {"identity_sigma", sigma},
          {"identity_rigid_share_face", rigid_share},
          {"expression_components", m.num_expression()},
          {"expression_names", m.expression_names},
          {"albedo_components", m.num_albedo()},
          {"albedo_names", m.albedo_names},
          {"albedo_sigma", asigma},
          {"landmarks", m.landmarks.size()},
          {"landmarks_silhouette", silhouette},
          {"landmarks_inner", inner},
          {"landmark_vertices", landmarks},
          // The hm08 base-mesh index of every model vertex (data/ibug68_landmarks.json binds hm08 indices).
          {"base_vertex", m.base_vertex},
          {"mean_face_extent", {hi.x() - lo.x(), hi.y() - lo.y(), hi.z() - lo.z()}},
          {"eye_centre_distance", eye_centre_distance(m)}};
}

void print_info(const nlohmann::json& j) {
  auto s = [&](const char* k) { return j[k].get<std::string>(); };
  std::printf("Face model %s (%.1f MB, loaded in %.1f ms)\n", s("file").c_str(),
              j["file_bytes"].get<double>() / 1e6, j["load_ms"].get<double>());
  std::printf("  source       %s\n", s("source").c_str());
  std::printf("  units        %s (+x person's left, +y up, +z out of the face; origin between the eyes)\n",
              s("units").c_str());
  std::printf("  geometry     %d vertices, %d triangles\n", j["vertices"].get<int>(), j["triangles"].get<int>());
  std::printf("  parts       ");
  for (auto& [name, count] : j["parts"].items()) std::printf(" %s=%d", name.c_str(), count.get<int>());
  auto ext = j["mean_face_extent"];
  std::printf("\n  mean face    %.0f x %.0f x %.0f mm (w x h x d), eye centres %.1f mm apart\n",
              1000 * ext[0].get<double>(), 1000 * ext[1].get<double>(), 1000 * ext[2].get<double>(),
              1000 * j["eye_centre_distance"].get<double>());
  std::printf("  identity     %d components, %.2f%% of the variance of %llu sampled heads; %.1f%% of it over "
              "the face region is rigid motion\n",
              j["identity_components"].get<int>(), 100 * j["identity_explained_variance"].get<double>(),
              j["identity_samples"].get<unsigned long long>(), 100 * j["identity_rigid_share_face"].get<double>());
  std::printf("  expression   %d ARKit blendshapes\n", j["expression_components"].get<int>());
  std::printf("  albedo       %d components:", j["albedo_components"].get<int>());
  for (auto& n : j["albedo_names"]) std::printf(" %s", n.get<std::string>().c_str());
  std::printf("\n  landmarks    %d (iBUG 68; %d silhouette, %d inner)\n", j["landmarks"].get<int>(),
              j["landmarks_silhouette"].get<int>(), j["landmarks_inner"].get<int>());
}

FacePart parse_part(const std::string& name) {
  for (int p = 0; p < kNumFaceParts; ++p)
    if (name == face_part_name(static_cast<FacePart>(p))) return static_cast<FacePart>(p);
  std::string all;
  for (int p = 0; p < kNumFaceParts; ++p) all += std::string(all.empty() ? "" : ", ") + face_part_name(FacePart(p));
  throw Error("unknown part '" + name + "' (known: " + all + ")");
}

Eigen::VectorXf random_coefficients(const Eigen::VectorXf& sigma, uint64_t seed, float scale) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> g;
  Eigen::VectorXf c(sigma.size());
  for (Eigen::Index i = 0; i < c.size(); ++i) c[i] = scale * sigma[i] * g(rng);
  return c;
}

struct ExportOptions {
  std::string model, out;
  std::optional<uint64_t> identity_seed, albedo_seed;
  float identity_scale = 1.f;
  std::vector<std::string> expressions;  // NAME=WEIGHT
  std::vector<std::string> parts;
};

void run_export(const ExportOptions& o) {
  LoadedModel l = load(o.model);
  const FaceModel& m = l.model;
  Eigen::VectorXf alpha = Eigen::VectorXf::Zero(m.num_identity());
  Eigen::VectorXf beta = Eigen::VectorXf::Zero(m.num_albedo());
  Eigen::VectorXf delta = Eigen::VectorXf::Zero(m.num_expression());
  if (o.identity_seed) alpha = random_coefficients(m.identity_sigma, *o.identity_seed, o.identity_scale);
  if (o.albedo_seed) beta = random_coefficients(m.albedo_sigma, *o.albedo_seed, 1.f);
  for (const auto& e : o.expressions) {
    auto eq = e.find('=');
    if (eq == std::string::npos) throw Error("--expression takes NAME=WEIGHT, got '" + e + "'");
    std::string name = e.substr(0, eq);
    auto it = std::find(m.expression_names.begin(), m.expression_names.end(), name);
    if (it == m.expression_names.end())
      throw Error("unknown expression '" + name + "' (see 'face-reenact model info' for the 52 names)");
    char* end = nullptr;
    std::string w = e.substr(eq + 1);
    float weight = std::strtof(w.c_str(), &end);
    if (w.empty() || *end != '\0' || !std::isfinite(weight) || weight < 0.f || weight > 1.f)
      throw Error("expression weight for '" + name + "' must be a number in [0, 1], got '" + w + "'");
    delta[it - m.expression_names.begin()] = weight;
  }
  std::vector<FacePart> parts;
  for (const auto& p : o.parts) parts.push_back(parse_part(p));
  MeshInstance inst{m.shape(alpha, delta), m.albedo(beta)};
  export_mesh(m, inst, parts, o.out);
  std::printf("wrote %s (%d vertices in the model%s)\n", o.out.c_str(), m.num_vertices(),
              parts.empty() ? "" : ", selected parts only");
}

void add_model_commands(CLI::App& app) {
  CLI::App* model = get_or_add_subcommand(app, "model", "Build, inspect and export the parametric face model");

  auto* info = model->add_subcommand("info", "Describe a face model file");
  auto info_path = std::make_shared<std::string>();
  auto info_json = std::make_shared<bool>(false);
  info->add_option("--model", *info_path, "Face model file (default: the one next to the program)");
  info->add_flag("--json", *info_json, "Machine-readable output");
  info->callback([info_path, info_json] {
    nlohmann::json j = describe(load(*info_path));
    if (*info_json)
      std::cout << j.dump(2) << std::endl;
    else
      print_info(j);
  });

  auto* exp = model->add_subcommand("export", "Write one face of the model as an OBJ or PLY mesh");
  auto o = std::make_shared<ExportOptions>();
  exp->add_option("--model", o->model, "Face model file (default: the one next to the program)");
  exp->add_option("--out", o->out, "Output mesh (.obj or .ply)")->required();
  exp->add_option_function<uint64_t>(
      "--identity-random", [o](const uint64_t& s) { o->identity_seed = s; },
      "Draw a random identity from the PCA prior with this seed (default: the mean face)");
  exp->add_option("--identity-scale", o->identity_scale, "Scale of the random identity in standard deviations")
      ->check(CLI::Range(0.f, 3.f));
  exp->add_option_function<uint64_t>(
      "--albedo-random", [o](const uint64_t& s) { o->albedo_seed = s; },
      "Draw a random albedo from the prior with this seed (default: the mean albedo)");
  exp->add_option("--expression", o->expressions, "Blendshape weight NAME=WEIGHT, e.g. jawOpen=0.7 (repeatable)");
  exp->add_option("--parts", o->parts, "Only these parts (face, scalp, ear, neck, upper_teeth, ...)")->delimiter(',');
  exp->callback([o] { run_export(*o); });
}

}  // namespace

FR_REGISTER_COMMANDS(model, add_model_commands);

}  // namespace face_reenact::cli
