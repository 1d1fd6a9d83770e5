// The session's link to the reenactment pipeline (core/reenact/.../reenactment_pipeline.h).
#include <algorithm>
#include <optional>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/reenact/reenactment_pipeline.h"
#include "face_reenact/tracker/solver_choice.h"
#include "frame_processor.h"

namespace face_reenact::live {
namespace {

TrackingState tracking_from(reenact::TrackingStatus status) {
  switch (status) {
    case reenact::TrackingStatus::kCalibrating: return TrackingState::kCalibrating;
    case reenact::TrackingStatus::kTracking: return TrackingState::kTracking;
    case reenact::TrackingStatus::kLost: return TrackingState::kLost;
  }
  return TrackingState::kOff;
}

// The pipeline's own stage times as the live session's rows.
LiveStageTimes stage_rows(const reenact::ReenactedFrame& r) {
  const tracker::StageTimes& t = r.tracked.times;
  LiveStageTimes out;
  out.input_ms = std::max(0.0, r.times.track_ms - t.total_ms);  // track_ms = input conversion + Track()
  out.landmarks_ms = t.landmarks_ms;
  out.pose_init_ms = t.pose_init_ms;
  out.pyramid_ms = t.pyramid_ms;
  out.synthesis_ms = t.synthesis_ms;
  out.analysis_ms = t.analysis_ms;
  out.calibration_ms = t.calibration_ms;
  out.gaze_ms = t.gaze_ms;
  out.tracker_other_ms = std::max(0.0, t.total_ms - (t.landmarks_ms + t.pose_init_ms + t.pyramid_ms + t.synthesis_ms +
                                                     t.analysis_ms + t.calibration_ms + t.gaze_ms));
  out.transfer_ms = r.times.transfer_ms;
  out.render_ms = r.times.render_ms;
  out.detail_ms = r.times.detail_ms;
  out.mouth_ms = r.times.mouth_ms;
  out.composite_ms = r.times.composite_ms;
  return out;
}

class ReenactProcessor : public FrameProcessor {
 public:
  ReenactProcessor(const std::string& model_path, const PipelineSettings& settings, std::stop_token stop)
      : model_(load_face_model(model_path)) {
    const OutputMode mode = settings.mode;
    // Loading is a few long steps; a session stopped meanwhile skips the ones left.
    auto check_stop = [&] {
      if (stop.stop_requested()) throw Error("the session stopped while the pipeline was loading");
    };
    check_stop();
    reenact::ReenactmentOptions options;
    options.tracker.stop = stop;
    // The joint calibration solve takes seconds; on a thread of its own the worker keeps
    // publishing the input meanwhile instead of freezing the picture.
    options.tracker.background_calibration = true;
    // The albedo texture's build (0.1-0.2 s) likewise, beside the frames.
    options.albedo_texture.background = true;
    if (!tracker::parse_solver_backend(settings.solver, &options.tracker.solver))
      throw Error("unknown tracker solver '" + settings.solver + "'");
    options.mode = mode == OutputMode::kPassThrough ? reenact::ReenactMode::kPassThrough
                   : mode == OutputMode::kOverlay   ? reenact::ReenactMode::kOverlay
                   : mode == OutputMode::kMirror    ? reenact::ReenactMode::kMirror
                                                    : reenact::ReenactMode::kReenact;
    if (mode == OutputMode::kMirror)
      options.mirror = reenact::MirrorOptionsFromSettings(settings.mirror.texture, settings.mirror.at,
                                                          settings.mirror.opacity, settings.mirror.light);
    options.renderer = settings.use_vulkan ? reenact::RendererKind::kVulkan : reenact::RendererKind::kCpu;
    options.detail.mode = settings.detail;
    if (!options.SetMouth(settings.mouth)) throw Error("unknown mouth setting '" + settings.mouth + "'");
    options.teeth_texture = reenact::LoadDefaultTeethTexture(model_path, nullptr);
    target_ = std::make_unique<reenact::ReenactmentPipeline>(model_, options);
    if (settings.with_actor) {
      check_stop();
      // The source actor is only tracked (mode kOff renders nothing); its parameters and
      // calibrated neutral give the expression to transfer.
      reenact::ReenactmentOptions actor_options = options;
      actor_options.mode = reenact::ReenactMode::kOff;
      actor_ = std::make_unique<reenact::ReenactmentPipeline>(model_, actor_options);
      actor_thread_ = std::make_unique<NamedThread>("fr-actor-fit");
    }
  }

  // The worker's half: the source actor's frame, the source expression, the target's fit, and
  // what the status needs from the tracker (read here: the next Track may change it meanwhile).
  struct Staged : StagedFrame {
    reenact::TrackedTarget target;
    reenact::SourceExpression source;
    bool has_source = false;
    std::string calibration_warning;
    bool wants_relaxed_face = false;
    std::string calibration_progress;
    double actor_ms = 0;
  };

  struct Prepared : PreparedFrame {
    reenact::PreparedTarget target;
  };

  std::unique_ptr<PreparedFrame> prepare(const capture::RgbdFrame& target) override {
    auto prepared = std::make_unique<Prepared>();
    prepared->target = target_->Prepare(target);
    return prepared;
  }

  std::unique_ptr<StagedFrame> track(const capture::RgbdFrame& target, const ExpressionInput& input,
                                     ActorOutcome* actor_out) override {
    return track_prepared(target, input, actor_out, nullptr);
  }

  std::unique_ptr<StagedFrame> track_prepared(const capture::RgbdFrame& target, const ExpressionInput& input,
                                              ActorOutcome* actor_out,
                                              std::unique_ptr<PreparedFrame> prepared) override {
    auto staged = std::make_unique<Staged>();
    ActorOutcome actor_outcome;
    // The source actor's tracker is independent of the target's: it runs on a kept thread of its
    // own while the target is tracked (both cores work; `reenact` does the same), and the frame waits
    // for it only where it takes longer (ActorOutcome::ms).
    std::optional<reenact::ReenactedFrame> actor_result;
    auto track_target = [&] {
      staged->target = prepared ? target_->Track(std::move(static_cast<Prepared&>(*prepared).target))
                                : target_->Track(target);
    };
    if (actor_ && input.actor_frame) {
      actor_result = RunBeside(*actor_thread_, [&] { return actor_->Process(*input.actor_frame, nullptr); },
                               track_target, &actor_outcome.ms);
    } else {
      track_target();
    }
    if (actor_result) {
      const reenact::ReenactedFrame& actor = *actor_result;
      if (actor.status == reenact::TrackingStatus::kTracking) {
        actor_expression_ = reenact::SourceFromParameters(actor.target_params, actor_->target_neutral());
        // The actor's frame goes along for its folds and wrinkles (Sec. 7.3) and its mouth; a
        // copy, since the grabber reuses its buffers. None when the options use neither.
        if (target_->options().UsesSourceView())
          actor_expression_.view = std::make_shared<reenact::SourceView>(reenact::SourceView{
              input.actor_frame->color.clone(), actor.tracked.camera, actor.target_params, input.actor_frame->index});
        have_actor_expression_ = true;
        actor_outcome.tracked = true;
      } else {
        actor_outcome.calibrating = actor.status == reenact::TrackingStatus::kCalibrating;
        if (actor_outcome.calibrating) actor_outcome.calibration_progress = actor_->calibration_progress().Brief();
      }
    }
    if (actor_out) *actor_out = actor_outcome;
    if (input.remote) {
      staged->source = reenact::SourceFromRemote(*input.remote);
      staged->has_source = true;
    } else if (have_actor_expression_) {
      staged->source = actor_expression_;
      staged->has_source = true;
    }
    staged->calibration_warning = target_->calibration_warning();
    staged->wants_relaxed_face = target_->watching_for_relaxed_face();
    if (staged->target.frame.status == reenact::TrackingStatus::kCalibrating)
      staged->calibration_progress = target_->calibration_progress().Brief();
    if (actor_ && !actor_->calibration_warning().empty())
      staged->calibration_warning += (staged->calibration_warning.empty() ? "" : "; ") +
                                     ("source actor: " + actor_->calibration_warning());
    staged->actor_ms = actor_outcome.ms;
    return staged;
  }

  ProcessedFrame render(std::unique_ptr<StagedFrame> base) override {
    Staged& staged = static_cast<Staged&>(*base);
    ProcessedFrame out;
    reenact::ReenactedFrame result =
        target_->Render(std::move(staged.target), staged.has_source ? &staged.source : nullptr);
    out.bgr = result.bgr;
    out.times = stage_rows(result);
    out.times.actor_ms = staged.actor_ms;
    out.tracking = tracking_from(result.status);
    out.message = result.message;
    out.calibration_warning = staged.calibration_warning;
    out.wants_relaxed_face = staged.wants_relaxed_face && !staged.calibration_warning.empty();
    if (result.status == reenact::TrackingStatus::kCalibrating) out.calibration_progress = staged.calibration_progress;
    // The reenacted mouth wants a still of the target's own open mouth (mouth_interior.h); until
    // there is one the status asks for it. Render's side owns the still: read here.
    const reenact::ReenactmentOptions& o = target_->options();
    out.wants_open_mouth = result.status == reenact::TrackingStatus::kTracking && o.mode == reenact::ReenactMode::kReenact &&
                           o.render_mouth && o.mouth_exemplar && o.mouth_exemplar_frame < 0 && target_->mouth_exemplar().empty();
    out.wants_head_turn = result.status == reenact::TrackingStatus::kTracking && o.mode == reenact::ReenactMode::kReenact &&
                          target_->wants_side_views();
    return out;
  }

  void request_calibration() override {
    target_->RequestCalibration();
    if (actor_) actor_->RequestCalibration();
  }

  std::string tracking_solver() const override { return target_->tracking_solver(); }
  bool tracking_solves_on_gpu() const override { return target_->tracking_solves_on_gpu(); }

 private:
  FaceModel model_;  // outlives the pipelines (declared first)
  std::unique_ptr<reenact::ReenactmentPipeline> target_;
  std::unique_ptr<reenact::ReenactmentPipeline> actor_;
  std::unique_ptr<NamedThread> actor_thread_;  // the actor's fit, beside the target's (after actor_: joins first)
  reenact::SourceExpression actor_expression_;
  bool have_actor_expression_ = false;
};

}  // namespace

std::shared_ptr<FrameProcessor> make_reenactment_processor(const std::string& model_path, const PipelineSettings& settings,
                                                           std::stop_token stop) {
  return std::make_shared<ReenactProcessor>(model_path, settings, std::move(stop));
}

}  // namespace face_reenact::live
