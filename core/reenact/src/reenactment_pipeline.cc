#include "face_reenact/reenact/reenactment_pipeline.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <future>
#include <mutex>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/common/srgb.h"
#include "face_reenact/common/timing.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/reenact/face_compositor.h"
#include "face_reenact/reenact/fit_overlay.h"
#include "face_reenact/reenact/transfer.h"

namespace face_reenact::reenact {
namespace {

using Clock = std::chrono::steady_clock;

// The albedo map learns from the first tracked frames densely, then keeps refining slowly (a
// render per observation).
constexpr int kDenseAlbedoFrames = 8;
constexpr int kAlbedoRefreshInterval = 15;
// The albedo texture is rebuilt for a better view at most once per this many tracked frames (a
// build unwraps every view again: tens of milliseconds at 2048).
constexpr int kAlbedoTextureRebuildFrames = 30;
constexpr int kLandmarkResetFrames = 3;
// The source actor's opening stands in for the target's from this size on (a slit shows lips).
constexpr double kSourceMouthMinAreaPx = 30.0;
// ... and with the source's head up to this far from facing its camera. The still the target keeps
// must face the camera (MouthExemplarOptions::max_turn_deg, 20), since every later opening is
// warped from it; the source's mouth of this very frame is warped into an opening the output
// opens as the source does. A source filmed from below (liveportrait_d10, pitched 17-28 degrees:
// a phone held low) was refused on 58 of 86 frames, and the output's opened mouth was the model's
// flat dark cavity, a black gash (d10 onto the webcam clip, output frames 40 and 80).
constexpr float kSourceMouthMaxTurnDeg = 35.f;

TrackingStatus coarse_status(tracker::TrackingStatus s) {
  switch (s) {
    case tracker::TrackingStatus::kCalibrating: return TrackingStatus::kCalibrating;
    case tracker::TrackingStatus::kCalibrated:
    case tracker::TrackingStatus::kTracking:
    case tracker::TrackingStatus::kRecovered: return TrackingStatus::kTracking;
    case tracker::TrackingStatus::kLost:
    case tracker::TrackingStatus::kNoFace:
    case tracker::TrackingStatus::kBadInput: return TrackingStatus::kLost;
  }
  return TrackingStatus::kLost;
}

void add_times(StageTimes* sum, const StageTimes& t) {
  sum->track_ms += t.track_ms;
  sum->transfer_ms += t.transfer_ms;
  sum->render_ms += t.render_ms;
  sum->mouth_ms += t.mouth_ms;
  sum->composite_ms += t.composite_ms;
  sum->detail_ms += t.detail_ms;
  sum->total_ms += t.total_ms;
}

}  // namespace

bool ReenactmentOptions::SetMouth(const std::string& name) {
  if (name != "auto" && name != "target" && name != "model") return false;
  mouth_exemplar = name != "model";
  source_mouth = name == "auto";
  return true;
}

bool ReenactmentOptions::UsesSourceView() const {
  return detail.mode != DetailMode::kOff || (source_mouth && mouth_exemplar && render_mouth);
}

bool ReenactmentOptions::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (mode != ReenactMode::kReenact && mode != ReenactMode::kPassThrough && mode != ReenactMode::kOff &&
      mode != ReenactMode::kOverlay && mode != ReenactMode::kMirror)
    return fail("unknown reenactment mode");
  if (mode == ReenactMode::kMirror && !mirror.IsValid(why)) return false;
  if (mode == ReenactMode::kMirror && mirror.texture.empty() && mirror.light.kind == MirrorLight::Kind::kTracked)
    return fail("the mirror mode needs a texture to paint on the face or a light");
  if (renderer != RendererKind::kCpu && renderer != RendererKind::kVulkan) return fail("unknown renderer kind");
  if (appearance != Appearance::kFrameTexture && appearance != Appearance::kAlbedoMap)
    return fail("unknown appearance");
  if (!std::isfinite(mouth_open_threshold) || mouth_open_threshold < 0.f || mouth_open_threshold > 1.f)
    return fail("mouth_open_threshold must be in [0, 1]");
  if (!std::isfinite(frame_texture_boundary_px) || frame_texture_boundary_px < 0.f || frame_texture_boundary_px > 20.f)
    return fail("frame_texture_boundary_px must be in [0, 20]");
  if (blend_levels < 1 || blend_levels > 10) return fail("blend_levels must be in [1, 10]");
  if (!std::isfinite(mask_erosion_px) || mask_erosion_px < 0.f || mask_erosion_px > 50.f)
    return fail("mask_erosion_px must be in [0, 50]");
  if (!std::isfinite(mask_feather_px) || mask_feather_px < 0.f || mask_feather_px > 50.f)
    return fail("mask_feather_px must be in [0, 50]");
  if (!std::isfinite(depth_background_m) || depth_background_m < 0.f || !std::isfinite(depth_occluder_m) ||
      depth_occluder_m < 0.f)
    return fail("depth_background_m and depth_occluder_m must be finite and >= 0");
  if (render_threads < 0 || render_threads > 64) return fail("render_threads must be 0..64 (0 = one per hardware thread)");
  if (mouth_exemplar_frame < -1) return fail("mouth_exemplar_frame must be -1 (automatic) or a frame index");
  std::string sub;
  if (!mouth_exemplar_options.IsValid(&sub)) return fail(sub);
  if (!detail.IsValid(&sub)) return fail(sub);
  if (!albedo_texture.IsValid(&sub)) return fail(sub);
  if (!use_ground_truth_target) {
    if (!tracker.IsValid(&sub)) return fail("tracker: " + sub);
    if (!input.IsValid(&sub)) return fail("input: " + sub);
  }
  return true;
}

std::string PipelineSummary::BriefReport() const {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(1);
  s << frames << " frames (" << reenacted_frames << " reenacted, " << calibrating_frames << " calibrating, "
    << lost_frames << " lost); mean ms/frame: track " << mean_times.track_ms << ", transfer " << mean_times.transfer_ms
    << ", render " << mean_times.render_ms << ", mouth " << mean_times.mouth_ms << ", composite "
    << mean_times.composite_ms << ", detail " << mean_times.detail_ms << ", total " << mean_times.total_ms;
  if (!renderer.empty()) s << "; renderer " << renderer;
  return s.str();
}

struct ReenactmentPipeline::Impl {
  const FaceModel& model;
  ReenactmentOptions options;
  FaceCompositor compositor;
  std::unique_ptr<VirtualMirror> mirror;  // ReenactMode::kMirror
  std::unique_ptr<tracker::FaceTracker> tracker;
  std::unique_ptr<tracker::RgbdInput> input;
  // What Track tells the landmark detector for its next frame: the fitted pose and whether to start
  // a fresh detection. Prepare applies it, on whichever thread runs Prepare (Track may run beside).
  std::mutex input_feedback_mu;
  gpu::FaceParameters input_pose;
  bool input_pose_has_fit = false, input_pose_pending = false, input_reset_pending = false;
  TrackingStatus status = TrackingStatus::kCalibrating;
  gpu::FaceParameters neutral;
  AlbedoMap albedo;
  int albedo_observations = 0;
  // The albedo texture's views (AlbedoViewChooser's slots): the frames kept until the next build.
  using KeptView = FaceCompositor::AlbedoTextureFrame;
  std::shared_ptr<const AlbedoTextureLayout> texture_layout;
  AlbedoViewChooser view_chooser;
  KeptView kept_views[AlbedoViewChooser::kSlots];
  bool views_changed = false;
  int texture_built_at = 0;  // tracked_frames at the last build
  MouthExemplar mouth;
  EyeExemplar eyes;  // the target's open eyes: the latest frame that showed them, refreshed now and then
  DetailTransfer detail;  // the source actor's frames: kept across target recalibrations
  int tracked_frames = 0;
  int frames_without_face = 0;
  PipelineSummary summary;
  StageTimes time_sums;
  // What a build made: the texture (and the layout, kept for the next), or why there is none.
  struct BuildResult {
    std::shared_ptr<const AlbedoTextureLayout> layout;
    std::shared_ptr<const AlbedoTexture> texture;
    std::string error;
  };
  // A background build of the albedo texture in flight (AlbedoTextureOptions::background), on a
  // kept thread started with the first. The thread is the last member: destroyed first, it
  // finishes the build, which reads the compositor and the model.
  std::future<BuildResult> texture_build;
  std::unique_ptr<NamedThread> texture_thread;

  Impl(const FaceModel& m, const ReenactmentOptions& o)
      : model(m), options(o), compositor(m, o), view_chooser(o.albedo_texture), detail(m, o.detail) {
    if (options.mode == ReenactMode::kMirror) mirror = std::make_unique<VirtualMirror>(m, options.mirror);
    neutral = gpu::frontal_pose(0.6f);
    MakeTracker();
  }

  void MakeTracker() {
    tracker.reset();
    input.reset();
    input_pose_pending = input_reset_pending = false;
    if (options.use_ground_truth_target) return;
    tracker = std::make_unique<tracker::FaceTracker>(model, options.tracker);
    input = std::make_unique<tracker::RgbdInput>(options.input);
  }

  void ForgetActor() {
    if (texture_build.valid()) texture_build.wait();  // its views are the actor's being forgotten
    texture_build = {};
    albedo = AlbedoMap{};
    albedo_observations = 0;
    view_chooser.Reset();
    for (auto& k : kept_views) k = KeptView{};
    views_changed = false;
    texture_built_at = 0;
    mouth = MouthExemplar{};
    eyes = EyeExemplar{};
    tracked_frames = 0;
  }

  // Keeps this tracked frame when it is a better view for the albedo texture, and builds the
  // texture once the per-vertex map has its first observations (the texture is blended over it),
  // again for a better view at most every kAlbedoTextureRebuildFrames. With
  // AlbedoTextureOptions::background the build runs on a thread of its own and a later frame
  // takes the result. Returns the time spent on this thread.
  double UpdateAlbedoTexture(const cv::Mat& frame_bgr, const cv::Mat& depth, int64_t frame_index,
                             const gpu::PinholeCamera& camera, const gpu::FaceParameters& params) {
    if (options.albedo_texture.size <= 0) {
      if (summary.albedo_texture_note.empty()) summary.albedo_texture_note = "off";
      return 0;
    }
    const auto start = Clock::now();
    if (texture_build.valid() && texture_build.wait_for(std::chrono::seconds(0)) == std::future_status::ready)
      TakeAlbedoTexture(texture_build.get());
    const AlbedoViewChooser::Slot slot = view_chooser.Consider(params);
    if (slot != AlbedoViewChooser::kNone) {
      kept_views[slot] = KeptView{frame_bgr.clone(), depth.empty() ? cv::Mat() : depth.clone(), camera, params, frame_index,
                                  slot == AlbedoViewChooser::kClosedEyes};
      views_changed = true;
    }
    if (!views_changed || albedo_observations < kDenseAlbedoFrames || texture_build.valid()) return ms_since(start);
    if (albedo.texture && tracked_frames - texture_built_at < kAlbedoTextureRebuildFrames) return ms_since(start);
    views_changed = false;
    texture_built_at = tracked_frames;
    // The build reads copies (the kept frames are never written in place, a new view replaces
    // its slot's Mat) and the compositor's const, CPU-only unwrap.
    std::vector<KeptView> views;
    for (const KeptView& k : kept_views)
      if (!k.bgr.empty()) views.push_back(k);
    auto build = [this, views = std::move(views), base = Eigen::VectorXf(albedo.albedo),
                  size = options.albedo_texture.size, levels = options.albedo_texture.blend_levels,
                  layout = texture_layout]() mutable -> BuildResult {
      BuildResult r;
      try {
        if (!layout) layout = AlbedoTextureLayout::ForModel(model, size);
        r.layout = layout;
        r.texture = std::make_shared<const AlbedoTexture>(compositor.BuildAlbedoTexture(views, layout, base, levels));
      } catch (const Error& e) {
        r.error = e.what();
      }
      return r;
    };
    if (options.albedo_texture.background) {
      if (!texture_thread) texture_thread = std::make_unique<NamedThread>("fr-albedo-tex");
      texture_build = texture_thread->Submit(std::move(build));
    } else {
      TakeAlbedoTexture(build());
    }
    return ms_since(start);
  }

  void TakeAlbedoTexture(BuildResult r) {
    if (r.layout) texture_layout = r.layout;
    ++summary.albedo_texture_builds;
    if (!r.texture) {
      // A model without a UV layout, a bad view: the per-vertex map alone, and the report says why.
      summary.albedo_texture_note = "none: " + r.error;
      options.albedo_texture.size = 0;
      return;
    }
    summary.albedo_texture_ms = r.texture->build_ms;
    summary.albedo_texture_views = r.texture->views;
    summary.albedo_texture_note.clear();
    albedo.texture = std::move(r.texture);
  }

  // Takes this tracked frame's open mouth as the interior when it is the one to keep
  // (ReenactmentOptions::mouth_exemplar*). The model is evaluated only for frames whose jawOpen
  // could beat the current still.
  void ConsiderMouthExemplar(const cv::Mat& frame_bgr, int64_t frame_index, const gpu::PinholeCamera& camera,
                             const gpu::FaceParameters& params) {
    if (!options.mouth_exemplar || !options.render_mouth) return;
    const float jaw = expression_weight(params.delta, kJawOpenIndex);
    MouthExemplarOptions eo = options.mouth_exemplar_options;
    if (options.mouth_exemplar_frame >= 0) {
      // The named frame, whatever its pose, as long as its mouth is open at all.
      if (frame_index != options.mouth_exemplar_frame || !mouth.empty()) return;
      eo.min_jaw_open = 0.f;
      eo.min_area_px = 1.0;
      eo.max_turn_deg = 90.f;
    } else if (jaw < eo.min_jaw_open || (!mouth.empty() && jaw <= mouth.jaw_open)) {
      return;
    }
    const float turn_deg = gpu::head_turn_from_camera_deg(params);
    const std::vector<Eigen::Vector2f> opening = compositor.MouthOpening(camera, params);
    if (!IsBetterMouthExemplar(mouth, opening, jaw, turn_deg, eo)) return;
    MouthExemplar e = CaptureMouthExemplar(frame_bgr, opening, jaw, frame_index, eo);
    if (!e.empty()) mouth = std::move(e);
  }

  // The source actor's mouth in this source frame, in the target's colours, for a target that has
  // not opened its own (ReenactmentOptions::source_mouth); empty when the source's mouth is not
  // open enough, is turned away, or either actor's skin around the mouth is not in view.
  MouthExemplar SourceMouth(const SourceView& view, const cv::Mat& target_bgr, const gpu::PinholeCamera& camera,
                            const gpu::FaceParameters& params) const {
    const float jaw = expression_weight(view.params.delta, kJawOpenIndex);
    MouthExemplarOptions eo = options.mouth_exemplar_options;
    // Any opening the output draws an interior for: the output opens as the source does.
    eo.min_jaw_open = options.mouth_open_threshold;
    eo.min_area_px = kSourceMouthMinAreaPx;
    eo.max_turn_deg = kSourceMouthMaxTurnDeg;
    const FaceCompositor::MouthView source = compositor.ViewMouth(view.bgr, view.camera, view.params);
    if (!IsBetterMouthExemplar(MouthExemplar{}, source.opening, jaw, gpu::head_turn_from_camera_deg(view.params), eo))
      return {};
    const FaceCompositor::MouthView target = compositor.ViewMouth(target_bgr, camera, params);
    if (!source.has_skin || !target.has_skin) return {};
    const Eigen::Vector3f &target_skin = target.skin, &source_skin = source.skin;
    MouthExemplar e = CaptureMouthExemplar(view.bgr, source.opening, jaw, view.frame_index, eo);
    if (e.empty()) return e;
    // The ratio of the two skins is the ratio of the two lights and cameras (and of the skins'
    // own tones, which a mouth's inside shares more than its teeth do); bounded, so a skin in a
    // shadow cannot turn the teeth white-hot or black.
    std::array<float, 3> gain{};
    for (int c = 0; c < 3; ++c) gain[static_cast<size_t>(c)] = std::clamp(target_skin[c] / std::max(source_skin[c], 1e-3f), 0.25f, 4.f);
    const auto& lut = srgb_decode_table();
    // A plain loop over the small crop: cv::Mat::forEach would start OpenCV's own thread pool on
    // the live session's threads (a thread more than the session names, seen by
    // LiveSessionActorTest.RecordedSourceActorRunsItsOwnCaptureAndIsReported).
    for (int j = 0; j < e.bgr.rows; ++j)
      for (cv::Vec3b& px : cv::Mat_<cv::Vec3b>(e.bgr.row(j)))
        for (int k = 0; k < 3; ++k)  // BGR: channel k is RGB channel 2 - k
          px[k] = static_cast<uchar>(std::lround(255.f * std::clamp(srgb_encode(lut[px[k]] * gain[static_cast<size_t>(2 - k)]), 0.f, 1.f)));
    return e;
  }

  std::string MouthInteriorDescription() const {
    if (!options.render_mouth) return "none: the mouth pass is off";
    if (!mouth.empty()) {
      std::ostringstream s;
      s.setf(std::ios::fixed);
      s.precision(2);
      s << "the target's own mouth, frame " << mouth.frame_index << " (jawOpen " << mouth.jaw_open << ", "
        << static_cast<int>(std::lround(mouth.area_px)) << " px opening)";
      return s.str();
    }
    const std::string teeth = options.teeth_texture && !options.teeth_texture->empty()
                                  ? "the model's teeth (textured from " + options.teeth_texture->source + ") and a dark cavity"
                                  : "the model's teeth and a dark cavity";
    if (!options.mouth_exemplar) return teeth + " (the target's own mouth is off)";
    const std::string source = summary.source_mouth_frames > 0
                                   ? "; the source actor's own mouth stood in on " +
                                         std::to_string(summary.source_mouth_frames) +
                                         (summary.source_mouth_frames == 1 ? " frame" : " frames")
                                   : "";
    if (options.mouth_exemplar_frame >= 0)
      return teeth + ": frame " + std::to_string(options.mouth_exemplar_frame) +
             " was not tracked with an open mouth in the frame" + source;
    return teeth + ": the target has not opened the mouth wide enough while facing the camera" + source;
  }
};

ReenactmentPipeline::ReenactmentPipeline(const FaceModel& model, const ReenactmentOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("reenactment options: " + why);
  // The landmark model's read (0.1-0.2 s) beside the compositor's and the tracker's set-up.
  if (!options.use_ground_truth_target) tracker::PreloadLandmarkModel(options.input);
  impl_ = std::make_unique<Impl>(model, options);
}

ReenactmentPipeline::~ReenactmentPipeline() = default;

void ReenactmentPipeline::RequestCalibration() { calibration_requested_.store(true); }

void ReenactmentPipeline::SetOptions(const ReenactmentOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("reenactment options: " + why);
  Impl& im = *impl_;
  const bool tracker_changed = options.use_ground_truth_target != im.options.use_ground_truth_target ||
                               options.input.landmark_source != im.options.input.landmark_source ||
                               options.input.use_depth != im.options.input.use_depth ||
                               options.tracker.calibration_frames != im.options.tracker.calibration_frames ||
                               options.tracker.solver != im.options.tracker.solver ||
                               options.tracker.solver_device != im.options.tracker.solver_device;
  // A background build of the albedo texture reads the compositor's options: let it finish (a
  // later frame takes its result).
  if (im.texture_build.valid()) im.texture_build.wait();
  im.compositor.SetOptions(options);
  im.detail.SetOptions(options.detail);
  im.options = options;
  if (tracker_changed) {
    im.MakeTracker();
    im.ForgetActor();
    im.status = TrackingStatus::kCalibrating;
  }
}

const ReenactmentOptions& ReenactmentPipeline::options() const { return impl_->options; }
TrackingStatus ReenactmentPipeline::status() const { return impl_->status; }
const gpu::FaceParameters& ReenactmentPipeline::target_neutral() const { return impl_->neutral; }
std::string ReenactmentPipeline::calibration_warning() const {
  return impl_->tracker ? impl_->tracker->calibration_warning() : std::string();
}

bool ReenactmentPipeline::watching_for_relaxed_face() const {
  return impl_->tracker && impl_->tracker->watching_for_relaxed_face();
}

tracker::FaceTracker::RelaxedRecalibration ReenactmentPipeline::relaxed_recalibration() const {
  return impl_->tracker ? impl_->tracker->relaxed_recalibration() : tracker::FaceTracker::RelaxedRecalibration();
}

tracker::FaceTracker::FocalLengthReport ReenactmentPipeline::focal_length_report() const {
  return impl_->tracker ? impl_->tracker->focal_length_report() : tracker::FaceTracker::FocalLengthReport();
}

std::string ReenactmentPipeline::tracking_solver() const {
  return impl_->tracker ? impl_->tracker->solver_description() : std::string();
}

bool ReenactmentPipeline::tracking_solves_on_gpu() const { return impl_->tracker && impl_->tracker->solves_on_gpu(); }

tracker::FaceTracker::CalibrationProgress ReenactmentPipeline::calibration_progress() const {
  return impl_->tracker ? impl_->tracker->calibration_progress() : tracker::FaceTracker::CalibrationProgress();
}

PipelineSummary ReenactmentPipeline::summary() const {
  PipelineSummary s = impl_->summary;
  s.renderer = impl_->compositor.renderer_description();
  s.mouth_interior = impl_->MouthInteriorDescription();
  s.detail = impl_->options.mode == ReenactMode::kReenact ? impl_->detail.Description() : "off (not reenacting)";
  if (s.frames > 0) {
    const double n = s.frames;
    const StageTimes& t = impl_->time_sums;
    s.mean_times = StageTimes{t.track_ms / n, t.transfer_ms / n, t.render_ms / n, t.mouth_ms / n,
                              t.composite_ms / n, t.total_ms / n, t.detail_ms / n};
  }
  return s;
}

const MouthExemplar& ReenactmentPipeline::mouth_exemplar() const { return impl_->mouth; }

bool ReenactmentPipeline::wants_side_views() const {
  const Impl& im = *impl_;
  return im.options.albedo_texture.size > 0 &&
         (!im.view_chooser.filled(AlbedoViewChooser::kLeft) || !im.view_chooser.filled(AlbedoViewChooser::kRight));
}

ReenactedFrame ReenactmentPipeline::Process(const capture::RgbdFrame& target, const SourceExpression* source) {
  std::string why;
  if (source && !source->IsValid(&why)) throw Error(why);
  return Render(Track(target), source);
}

TrackedTarget ReenactmentPipeline::Track(const capture::RgbdFrame& target) { return Track(Prepare(target)); }

PreparedTarget ReenactmentPipeline::Prepare(const capture::RgbdFrame& target) {
  Impl& im = *impl_;
  PreparedTarget p;
  TrackedTarget& tt = p.tracked;
  tt.start = Clock::now();
  ReenactedFrame& out = tt.frame;
  out.frame_index = target.index;
  p.camera = target.camera;
  auto pass_through = [&](TrackingStatus status, const std::string& message) -> PreparedTarget {
    out.status = status;
    out.message = message;
    out.reenacted = false;
    tt.finished = true;
    p.ms = ms_since(tt.start);
    out.times.track_ms = p.ms;
    return std::move(p);
  };

  // The output always has the input's size and type CV_8UC3, whatever arrives.
  const cv::Mat& color = target.color;
  if (color.empty()) {
    const int w = std::max(1, target.camera.width), h = std::max(1, target.camera.height);
    out.bgr = cv::Mat::zeros(h, w, CV_8UC3);
    return pass_through(TrackingStatus::kLost, "bad input: the target frame has no colour image");
  }
  if (color.type() == CV_8UC3) {
    out.bgr = color.clone();
  } else if (color.type() == CV_8UC1) {
    cv::cvtColor(color, out.bgr, cv::COLOR_GRAY2BGR);
  } else if (color.type() == CV_8UC4) {
    cv::cvtColor(color, out.bgr, cv::COLOR_BGRA2BGR);
  } else {
    out.bgr = cv::Mat::zeros(color.rows, color.cols, CV_8UC3);
    return pass_through(TrackingStatus::kLost, "bad input: the target colour image is not 8-bit");
  }
  if (color.type() != CV_8UC3)
    return pass_through(TrackingStatus::kLost, "bad input: the target colour image is not 3-channel BGR");
  if (color.cols != target.camera.width || color.rows != target.camera.height)
    return pass_through(TrackingStatus::kLost, "bad input: the colour image does not match the camera size");
  if (!target.depth.empty() && target.depth.type() == CV_32FC1 && target.depth.size() == color.size())
    out.depth = target.depth.clone();

  if (im.options.use_ground_truth_target) {
    if (!target.ground_truth.params)
      return pass_through(TrackingStatus::kLost, "no ground-truth parameters in the target frame");
    p.ground_truth = *target.ground_truth.params;
  } else if (im.input) {
    {
      // What the last finished Track asked of the detector (it may have run on another thread).
      std::lock_guard lock(im.input_feedback_mu);
      if (im.input_pose_pending) im.input->SetTrackedPose(im.input_pose, im.input_pose_has_fit);
      if (im.input_reset_pending) im.input->Reset();  // after the pose: a reset forgets it too
      im.input_pose_pending = im.input_reset_pending = false;
    }
    try {
      p.input = im.input->Convert(target, &p.info);
    } catch (const Error& e) {
      return pass_through(TrackingStatus::kLost, std::string("bad input: ") + e.what());
    }
  }
  p.ms = ms_since(tt.start);
  return p;
}

TrackedTarget ReenactmentPipeline::Track(PreparedTarget prepared) {
  Impl& im = *impl_;
  TrackedTarget tt = std::move(prepared.tracked);
  if (tt.finished) return tt;  // refused by Prepare: `frame` says why
  ReenactedFrame& out = tt.frame;
  auto pass_through = [&](TrackingStatus status, const std::string& message) -> TrackedTarget {
    out.status = status;
    out.message = message;
    out.reenacted = false;
    tt.finished = true;
    return std::move(tt);
  };

  if (calibration_requested_.exchange(false)) {
    if (im.tracker) im.tracker->RequestCalibration();
    tt.forget_actor = true;  // the appearance belongs to Render's side (another thread, maybe)
  }

  // --- track the target.
  auto t0 = Clock::now();
  auto track_ms = [&] { return prepared.ms + ms_since(t0); };
  gpu::FaceParameters target_params;
  gpu::PinholeCamera fit_camera = prepared.camera;  // the camera target_params are in
  std::vector<tracker::InputLandmark> detected;  // the detector's, for the overlay
  if (prepared.ground_truth) {
    target_params = *prepared.ground_truth;
    im.neutral = target_params;
    im.neutral.delta = Eigen::VectorXf::Zero(im.model.num_expression());
    out.status = TrackingStatus::kTracking;
  } else if (!im.tracker) {
    out.times.track_ms = track_ms();
    return pass_through(TrackingStatus::kLost, "the options changed between preparing and tracking the frame");
  } else {
    tracker::InputFrame& frame = prepared.input;
    if (im.options.mode == ReenactMode::kOverlay) detected = frame.landmarks;
    tt.eye_openings = EyeOpeningsFromLandmarks(frame.landmarks);
    out.tracked = im.tracker->Track(frame, prepared.info.landmarks_ms);
    if (im.input) im.input->Recycle(std::move(frame));  // read no further: its buffers are the next frame's
    if (out.tracked.new_face) tt.forget_actor = true;  // the learned appearance was the other face's
    const bool has_fit = out.tracked.has_parameters && tracker::tracking_status_has_fit(out.tracked.status);
    // A landmark track that keeps finding nothing is restarted from a fresh detection (measured:
    // once lost, the landmark tracker could stay empty on frames where a fresh one finds the face).
    im.frames_without_face = out.tracked.status == tracker::TrackingStatus::kNoFace ? im.frames_without_face + 1 : 0;
    const bool reset_detector = im.frames_without_face >= kLandmarkResetFrames;
    if (reset_detector) im.frames_without_face = 0;
    {
      // For the detector's next frame (Prepare, maybe on another thread).
      std::lock_guard lock(im.input_feedback_mu);
      im.input_pose = out.tracked.params;
      im.input_pose_has_fit = has_fit;
      im.input_pose_pending = true;
      im.input_reset_pending = im.input_reset_pending || reset_detector;
    }
    out.status = coarse_status(out.tracked.status);
    if (im.tracker->calibrated()) im.neutral = im.tracker->neutral();
    if (out.status == TrackingStatus::kTracking && !has_fit) out.status = TrackingStatus::kLost;
    target_params = out.tracked.params;
    // The camera the fit is in: the frame's, or the tracker's estimate for a video (focal_length.h).
    if (out.tracked.camera.width == prepared.camera.width && out.tracked.camera.height == prepared.camera.height)
      fit_camera = out.tracked.camera;
  }
  out.times.track_ms = track_ms();
  if (im.options.mode == ReenactMode::kOverlay && im.tracker) {
    // The fit over the input, whatever the status (a lost frame shows its landmarks and why).
    const auto to = Clock::now();
    const bool has_fit = out.tracked.has_parameters && tracker::tracking_status_has_fit(out.tracked.status);
    std::string status = tracker::tracking_status_name(out.tracked.status);
    if (out.status == TrackingStatus::kCalibrating) {
      const std::string progress = im.tracker->calibration_progress().Brief();
      if (!progress.empty()) status += " (" + progress + ")";
    }
    DrawFitOverlay(&out.bgr, im.tracker->model(), im.tracker->cpu_solver().renderer(), fit_camera,
                   has_fit ? &out.tracked.params : nullptr, detected,
                   OverlayStatusLine(status, out.tracked.agreement.pose_disagreement_deg, out.tracked.agreement.landmark_nme));
    out.times.render_ms = ms_since(to);
    out.target_params = out.tracked.params;
    out.message = out.tracked.message;
    tt.finished = true;
    return tt;
  }
  if (out.status != TrackingStatus::kTracking) {
    return pass_through(out.status, out.tracked.message.empty() ? std::string(tracking_status_name(out.status))
                                                                : out.tracked.message);
  }
  out.target_params = target_params;
  if (im.options.mode == ReenactMode::kOff) return pass_through(out.status, "reenactment is off");
  tt.camera = fit_camera;
  tt.neutral = im.neutral;  // Eq. 15's, as of this frame (the next Track may change it meanwhile)
  return tt;
}

EyeOpenings EyeOpeningsFromLandmarks(const std::vector<tracker::InputLandmark>& landmarks) {
  EyeOpenings openings;
  std::array<int, 2> found{0, 0};
  for (const tracker::InputLandmark& l : landmarks) {
    if (l.ibug_index < 36 || l.ibug_index > 47 || !(l.confidence > 0.f) || !l.position.allFinite()) continue;
    const int eye = l.ibug_index < 42 ? 0 : 1;
    openings.points[static_cast<size_t>(eye)][static_cast<size_t>(l.ibug_index - 36 - 6 * eye)] = l.position;
    ++found[static_cast<size_t>(eye)];
  }
  for (size_t e = 0; e < 2; ++e) openings.known[e] = found[e] == 6;
  return openings;
}

ReenactedFrame ReenactmentPipeline::Render(TrackedTarget tracked, const SourceExpression* source) {
  Impl& im = *impl_;
  std::string why;
  if (source && !source->IsValid(&why)) throw Error(why);
  if (tracked.forget_actor) im.ForgetActor();
  ReenactedFrame& out = tracked.frame;
  auto finish = [&]() -> ReenactedFrame {
    out.times.total_ms = ms_since(tracked.start);
    im.status = out.status;
    ++im.summary.frames;
    if (out.reenacted) ++im.summary.reenacted_frames;
    if (out.status == TrackingStatus::kLost) ++im.summary.lost_frames;
    if (out.status == TrackingStatus::kCalibrating) ++im.summary.calibrating_frames;
    add_times(&im.time_sums, out.times);
    return std::move(out);
  };
  auto pass_through = [&](TrackingStatus status, const std::string& message) -> ReenactedFrame {
    out.status = status;
    out.message = message;
    out.reenacted = false;
    return finish();
  };
  if (tracked.finished) return finish();
  const gpu::FaceParameters& target_params = out.target_params;
  const gpu::PinholeCamera& fit_camera = tracked.camera;

  if (im.mirror) {
    // The virtual mirror: the target's own expression, its face re-textured and re-lit.
    try {
      out.output_params = target_params;
      const MirrorResult m = im.mirror->Apply(out.bgr, fit_camera, target_params, out.depth.empty() ? nullptr : &out.depth);
      out.times.render_ms = m.render_ms;
      out.times.composite_ms = m.composite_ms;
      if (!m.drawn) return pass_through(TrackingStatus::kTracking, "the tracked face is outside the frame");
      out.bgr = m.bgr;
      out.reenacted = true;
    } catch (const Error& e) {
      return pass_through(TrackingStatus::kLost, std::string("the mirror failed: ") + e.what());
    }
    return finish();
  }

  // --- the target's appearance: its own per-vertex albedo, learned from its frames.
  ++im.tracked_frames;
  try {
    // A blink unfolds the upper lids, which open eyes show only folded (the map does not learn them
    // there): every frame that closes an eye that far teaches the map those lids (only those).
    static const int blink_left = arkit_blendshape_index("eyeBlinkLeft"), blink_right = arkit_blendshape_index("eyeBlinkRight");
    const float blink = std::max(expression_weight(target_params.delta, blink_left), expression_weight(target_params.delta, blink_right));
    const bool observe = im.albedo_observations < kDenseAlbedoFrames || im.tracked_frames % kAlbedoRefreshInterval == 0;
    if (observe || blink >= im.options.albedo_texture.min_closed_eyes_blink) {
      const auto ta = Clock::now();
      im.compositor.ObserveAlbedo(out.bgr, fit_camera, target_params, &im.albedo,
                                  out.depth.empty() ? nullptr : &out.depth, /*folded_lids_only=*/!observe);
      if (observe) ++im.albedo_observations;
      out.times.render_ms += ms_since(ta);
    }
    out.times.render_ms += im.UpdateAlbedoTexture(out.bgr, out.depth, out.frame_index, fit_camera, target_params);

    // --- transfer (Eq. 15).
    auto t0 = Clock::now();
    const bool transfer = im.options.mode == ReenactMode::kReenact && source != nullptr;
    out.output_params = transfer ? TransferParameters(target_params, tracked.neutral, *source) : target_params;
    out.times.transfer_ms = ms_since(t0);

    // --- the target's own open mouth, for the interior (Sec. 7.4.1).
    t0 = Clock::now();
    im.ConsiderMouthExemplar(out.bgr, out.frame_index, fit_camera, target_params);
    const double exemplar_ms = ms_since(t0);
    t0 = Clock::now();
    // The target's open eyes, for its blinks: refreshed every kEyeExemplarRefreshFrames (the light
    // and the pose drift; a frame's capture is a crop of the eyes and an evaluation of the model).
    constexpr int64_t kEyeExemplarRefreshFrames = 15;
    if (transfer && (im.eyes.empty() || out.frame_index - im.eyes.frame_index >= kEyeExemplarRefreshFrames ||
                     out.frame_index < im.eyes.frame_index) &&
        im.compositor.CaptureEyes(out.bgr, fit_camera, target_params, out.frame_index, &im.eyes, &tracked.eye_openings))
      im.summary.eye_exemplar_frame = im.eyes.frame_index;
    out.times.render_ms += ms_since(t0);

    // --- the source's frame for its folds and wrinkles (Sec. 7.3).
    t0 = Clock::now();
    const bool with_detail = transfer && source->view && im.options.detail.mode != DetailMode::kOff;
    if (with_detail) im.detail.Observe(*source->view, source->blend_weight);
    out.times.detail_ms = ms_since(t0);

    // --- the source actor's own mouth, until the target has shown its own.
    t0 = Clock::now();
    MouthExemplar source_mouth;
    if (transfer && source->view && im.mouth.empty() && im.options.source_mouth && im.options.mouth_exemplar &&
        im.options.render_mouth &&
        expression_weight(out.output_params.delta, kJawOpenIndex) > im.options.mouth_open_threshold)
      source_mouth = im.SourceMouth(*source->view, out.bgr, fit_camera, target_params);
    const double source_mouth_ms = ms_since(t0);
    const MouthExemplar* mouth = source_mouth.empty() ? &im.mouth : &source_mouth;

    // --- re-render, mouth, composite.
    const cv::Mat input_depth = out.depth.empty() ? cv::Mat() : out.depth.clone();
    CompositeResult c = im.compositor.Compose(out.bgr, fit_camera, target_params, out.output_params, &im.albedo,
                                              input_depth.empty() ? nullptr : &input_depth, mouth,
                                              with_detail ? &im.detail : nullptr, &im.eyes, &tracked.eye_openings);
    if (c.eyes_from_exemplar) ++im.summary.eye_exemplar_frames;
    out.times.detail_ms += c.detail.ms;
    if (c.detail.pixels > 0) ++im.summary.detail_frames;
    out.times.render_ms += c.render_ms;
    out.times.mouth_ms = c.mouth_ms + exemplar_ms + source_mouth_ms;
    out.times.composite_ms = c.composite_ms;
    if (!c.drawn) return pass_through(TrackingStatus::kTracking, "the tracked face is outside the frame");
    out.bgr = c.bgr;
    out.face_mask = c.face_mask;
    out.rendered = c.rendered_bgr;
    if (!out.depth.empty()) {
      c.face_depth.copyTo(out.depth, c.face_mask);
    }
    out.mouth_drawn = c.mouth_drawn;
    out.mouth_from_exemplar = c.mouth_from_exemplar;
    out.mouth_from_source = c.mouth_from_exemplar && !source_mouth.empty();
    if (out.mouth_from_source) ++im.summary.source_mouth_frames;
    out.reenacted = true;
  } catch (const Error& e) {
    // Non-finite or out-of-range tracked parameters: show the input, say why.
    return pass_through(TrackingStatus::kLost, std::string("reenactment failed: ") + e.what());
  }
  return finish();
}

}  // namespace face_reenact::reenact
