// `face-reenact mirror`: the virtual mirror (paper Sec. 7.5, 8.3) on a recording, a video or an
// OpenNI camera: each frame's face is tracked, re-textured with an image (a logo, make-up, a
// tattoo) and re-lit (a preset or a light file), and written out (reenact/virtual_mirror.h).
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "camera_options.h"
#include "command_registry.h"
#include "video_output.h"
#include "face_reenact/capture/recording.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/common/timing.h"
#include "face_reenact/live/frame_grabber.h"
#include "face_reenact/live/input_spec.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/reenact/virtual_mirror.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/rgbd_input.h"
#include "face_reenact/tracker/solver.h"

namespace face_reenact::cli {
namespace {

using namespace face_reenact::tracker;

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
  const reenact::MirrorOptions mo = reenact::MirrorOptionsFromSettings(a.texture, a.at, a.opacity, a.light);
  const FaceModel face_model = load_face_model(resolve_model_path(a.model));
  const TrackerModel model = TrackerModel::FromFaceModel(face_model);
  const reenact::VirtualMirror mirror(face_model, mo);

  std::unique_ptr<capture::FrameSource> source = live::open_offline_source(a.input, "mirror: --input", video_options(a.camera, "mirror"));
  const capture::RecordingInfo info = source->info();
  RgbdInputOptions io;
  io.use_depth = info.has_depth;
  RgbdInput input(io);
  TrackerOptions to;
  for (SolverOptions* s : {&to.calibration_solver, &to.tracking_solver, &to.recovery_solver}) {
    s->energy.use_point = s->energy.use_point && info.has_depth;
    s->energy.use_plane = s->energy.use_plane && info.has_depth;
  }
  to.focal_length.estimate = estimate_focal_length(a.camera, info);
  FaceTracker tracker(model, to);
  FrameOutput out(a.out, info.fps, cv::Size(info.camera.width, info.camera.height));
  const bool tty = isatty(2) != 0;
  int frames = 0, mirrored = 0, textured_frames = 0;
  double track_ms = 0, render_ms = 0, composite_ms = 0;
  capture::RgbdFrame frame;
  while (a.frames <= 0 || frames < a.frames) {
    if (!source->read_next(&frame)) break;
    RgbdInputInfo ii;
    const InputFrame in = input.Convert(frame, &ii);
    const TrackedFrame t = tracker.Track(in, ii.landmarks_ms);
    input.SetTrackedPose(t.params, tracking_status_has_fit(t.status));
    track_ms += t.times.total_ms;
    ++frames;
    // Only a fit that agrees with the frame is drawn: a face under calibration, lost or
    // recovering is shown unchanged (no texture sliding over the cheek).
    if (tracking_status_has_fit(t.status) && tracker.calibrated()) {
      const reenact::MirrorResult r = mirror.Apply(frame.color, t.camera, t.params);
      render_ms += r.render_ms;
      composite_ms += r.composite_ms;
      if (r.drawn) ++mirrored;
      if (r.textured_pixels > 0) ++textured_frames;
      out.write(r.bgr, frame.index);
    } else {
      out.write(frame.color, frame.index);
    }
    if (!a.quiet && (tty || frames % 10 == 0))
      std::fprintf(stderr, "%smirror: frame %d %-11s%s", tty ? "\r" : "", frames, tracking_status_name(t.status), tty ? "   " : "\n");
  }
  if (!a.quiet && tty) std::fprintf(stderr, "\n");
  out.close();
  if (frames == 0) throw Error("mirror: '" + a.input + "' has no frames");
  if (!a.quiet) {
    const double n = std::max(mirrored, 1);
    std::printf("wrote %s: %d frames, %d with the face changed (%d textured), the rest unchanged (calibrating, no face or "
                "lost)\n",
                a.out.c_str(), frames, mirrored, textured_frames);
    std::printf("mean ms/frame: track %.1f, render %.1f, texture+light %.1f; light: %s\n", track_ms / frames, render_ms / n,
                composite_ms / n, a.light.empty() ? "the tracked one" : mo.light.name.c_str());
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
