// `face-reenact mirror`: the virtual mirror (paper Sec. 7.5, 8.3) on a recording, a video or an
// OpenNI camera: each frame's face is tracked, re-textured with an image (a logo, make-up, a
// tattoo) and re-lit (a preset or a light file), and written out (reenact/virtual_mirror.h).
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include "camera_options.h"
#include "command_registry.h"
#include "video_output.h"
#include "face_reenact/capture/recording.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/live/frame_grabber.h"
#include "face_reenact/live/input_spec.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/reenact/reenactment_pipeline.h"
#include "face_reenact/reenact/virtual_mirror.h"
#include "face_reenact/tracker/face_tracker.h"

namespace face_reenact::cli {
namespace {

struct MirrorArgs {
  std::string input, out, model, texture, at = "face", light;
  float opacity = 1.0f;
  int frames = 0;
  bool quiet = false;
  CameraArgs camera;
};

void run_mirror(const MirrorArgs& a) {
  std::error_code ec;
  if (a.texture.empty() && a.light.empty()) throw Error("mirror: give --texture, --light or both (nothing to change otherwise)");
  const live::InputSpec spec = live::parse_target_spec(a.input, "mirror: --input");
  if (spec.kind == live::InputKind::kRecording && !std::filesystem::exists(a.input, ec))
    throw Error("mirror: '" + a.input + "': no such file or folder");
  if (std::filesystem::path(a.out).extension() == ".mp4") check_output_file(a.out, "--out");
  // The reenactment pipeline in its mirror mode: the target's own expression, and a frame whose
  // fit is not current (calibrating, no face, lost) passes unchanged, so no texture slides over a
  // cheek the fit has left.
  reenact::ReenactmentOptions ro;
  ro.mode = reenact::ReenactMode::kMirror;
  ro.mirror = reenact::MirrorOptionsFromSettings(a.texture, a.at, a.opacity, a.light);
  std::unique_ptr<capture::FrameSource> source = live::open_offline_source(a.input, "mirror: --input", video_options(a.camera, "mirror"));
  const capture::RecordingInfo info = source->info();
  ro.tracker.focal_length.estimate = estimate_focal_length(a.camera, info);
  const FaceModel face_model = load_face_model(resolve_model_path(a.model));
  reenact::ReenactmentPipeline pipeline(face_model, ro);
  FrameOutput out(a.out, info.fps, cv::Size(info.camera.width, info.camera.height));
  const bool tty = isatty(2) != 0;
  int frames = 0, mirrored = 0;
  double track_ms = 0, render_ms = 0, composite_ms = 0;  // render and composite over the frames changed
  capture::RgbdFrame frame;
  while (a.frames <= 0 || frames < a.frames) {
    if (!source->read_next(&frame)) break;
    const reenact::ReenactedFrame r = pipeline.Process(frame, nullptr);
    out.write(r.bgr, frame.index);
    ++frames;
    track_ms += r.times.track_ms;
    if (r.reenacted) {
      ++mirrored;
      render_ms += r.times.render_ms;
      composite_ms += r.times.composite_ms;
    }
    if (!a.quiet && (tty || frames % 10 == 0))
      std::fprintf(stderr, "%smirror: frame %d %-11s%s", tty ? "\r" : "", frames,
                   tracker::tracking_status_name(r.tracked.status), tty ? "   " : "\n");
  }
  if (!a.quiet && tty) std::fprintf(stderr, "\n");
  out.close();
  if (frames == 0) throw Error("mirror: '" + a.input + "' has no frames");
  if (!a.quiet) {
    const double n = std::max(mirrored, 1);
    std::printf("wrote %s: %d frames, %d with the face changed, the rest unchanged (calibrating, no face or lost)\n",
                a.out.c_str(), frames, mirrored);
    if (!a.texture.empty()) std::printf("the face textured with %s at %s\n", a.texture.c_str(), a.at.c_str());
    std::printf("mean ms/frame: track %.1f, render %.1f, texture+light %.1f; light: %s\n", track_ms / frames, render_ms / n,
                composite_ms / n, a.light.empty() ? "the tracked one" : ro.mirror.light.name.c_str());
  }
}

void add_mirror_commands(CLI::App& app) {
  auto args = std::make_shared<MirrorArgs>();
  CLI::App* c = app.add_subcommand(
      "mirror", "The virtual mirror: re-texture (a logo, make-up) and re-light the tracked face of a recording, video or camera");
  c->add_option("--input", args->input, "Recording folder, video file, .oni file or OpenNI device")->required();
  c->add_option("--out", args->out, "Output video (.mp4) or a folder (one PNG per frame)")->required();
  c->add_option("--texture", args->texture, "An image to paint on the face (PNG with alpha: transparent parts leave the skin)");
  c->add_option("--at", args->at,
                "Where: face, forehead, nose, left-cheek, right-cheek, chin (the person's left and right; the image keeps "
                "its aspect), or uv:U0,V0,U1,V1 in the model's MakeHuman texture layout (default: face)");
  c->add_option("--opacity", args->opacity, "The texture's opacity")->check(CLI::Range(0.0f, 1.0f));
  c->add_option("--light", args->light,
                "Re-light: front, left, right, top, bottom, warm, cool (as bright as the tracked light), or a .json with "
                "\"gamma\": 27 SH coefficients (a line of track's PARAMS.jsonl works)");
  c->add_option("--frames", args->frames, "Stop after this many frames (0 = all)");
  c->add_option("--model", args->model, "Face model file (default: the one next to the program)");
  add_camera_options(c, &args->camera);
  c->add_flag("--quiet", args->quiet, "No progress or summary");
  c->callback([args] { run_mirror(*args); });
}

}  // namespace

FR_REGISTER_COMMANDS(mirror, add_mirror_commands);

}  // namespace face_reenact::cli
