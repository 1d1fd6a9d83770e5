#pragma once
// The stateless part of the reenactment: given the target frame and two parameter vectors (the
// target's tracked P and the P to show), re-render the face (Sec. 7.4), draw the mouth interior
// (Sec. 7.3: teeth and tongue from the model's helper geometry, which the jawOpen/tongueOut
// blendshapes already move with the jaw, plus a dark cavity behind them), and composite with
// the Laplacian blend (Sec. 7.4.2). ReenactmentPipeline puts the tracker in front of it; tests
// drive it directly with ground-truth parameters.
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/reenact/albedo_texture.h"
#include "face_reenact/reenact/detail_transfer.h"
#include "face_reenact/reenact/mouth_interior.h"
#include "face_reenact/reenact/reenactment_pipeline.h"

namespace face_reenact {
struct FaceModel;
}

namespace face_reenact::reenact {

// Per-vertex albedo of one actor, learned from its own frames (the paper's per-actor albedo:
// the linear model cannot hold brows, lip colour, moles). Vertices never observed keep the
// model's albedo M_alb(beta).
struct AlbedoMap {
  Eigen::VectorXf albedo;  // 3N linear RGB
  Eigen::VectorXf weight;  // N, accumulated observation weight (0 = never seen)
  // Per channel, the brightest irradiance any observed vertex received in the last observation:
  // re-rendering never lights a vertex brighter than that (a lighting fit extrapolated to
  // normals it never saw can be far too bright, e.g. on a forehead the fit misplaced).
  Eigen::Vector3f max_irradiance = Eigen::Vector3f::Zero();
  // The actor's high-resolution albedo texture (albedo_texture.h), built from a few views;
  // null until then. Where it covers the face, the re-rendering takes its detail.
  std::shared_ptr<const AlbedoTexture> texture;
  bool empty() const { return albedo.size() == 0; }
};

// The target actor's open eyes: a frame in which the target held both eyes open, facing the
// camera, cropped around them, with its fit. Where the target's eyes close (a blink) and the
// output's stay open, the frame shows lids where the output shows eyeballs; they are drawn from
// this frame instead (FaceCompositor::CaptureEyes, Compose).
struct EyeExemplar {
  cv::Mat bgr;                  // CV_8UC3: the frame cropped around both eyes
  cv::Point origin;             // the crop's top-left in that frame
  gpu::PinholeCamera camera;    // the camera of that frame
  gpu::FaceParameters params;   // the target's tracked P in that frame
  EyeOpenings openings;         // the detector's lid points in that frame (its real eye openings)
  int64_t frame_index = -1;     // the frame it was taken from
  bool empty() const { return bgr.empty(); }
};

struct CompositeResult {
  cv::Mat bgr;            // CV_8UC3
  cv::Mat rendered_bgr;   // CV_8UC3: the rendered layers over the target (before blending)
  cv::Mat face_mask;      // CV_8UC1, 255 = covered by the re-rendered face layers
  cv::Mat mouth_mask;     // CV_8UC1, 255 = mouth interior drawn (cavity, teeth, tongue)
  cv::Mat face_depth;     // CV_32FC1, metres: camera-space z of the rendered layers; 0 where
                          // nothing was rendered and in the mouth opening (no surface measured)
  bool drawn = false;     // false: nothing of the face is in the frame; bgr = target
  bool mouth_drawn = false;
  bool mouth_opened_wider = false;  // the output's jawOpen exceeds the target's (by the threshold)
  bool mouth_from_exemplar = false;  // the interior drawn was the actor's own open mouth (mouth_interior.h)
  bool eyes_from_exemplar = false;   // an eyeball was drawn from the actor's open eyes (EyeExemplar)
  DetailStats detail;                // the source's wrinkle-level detail (detail_transfer.h); level -1: none
  double render_ms = 0, mouth_ms = 0, composite_ms = 0;
};

class FaceCompositor {
 public:
  // Throws face_reenact::Error on invalid options. `model` must outlive the compositor.
  FaceCompositor(const FaceModel& model, const ReenactmentOptions& options);
  ~FaceCompositor();
  FaceCompositor(const FaceCompositor&) = delete;
  FaceCompositor& operator=(const FaceCompositor&) = delete;

  void SetOptions(const ReenactmentOptions& options);

  // Renders `output` over `target_bgr` (CV_8UC3 of camera's size). `target` is the target's own
  // tracked P (reported: whether the mouth opened wider than the target's). The mouth interior
  // is drawn whenever the output's jawOpen exceeds options.mouth_open_threshold: the re-rendered
  // face covers the target's mouth, so an open rendered mouth needs its interior whether or not
  // the target's was open too. Throws
  // face_reenact::Error on invalid parameters or a mismatched image.
  // `target_depth` (optional, CV_32FC1 metres, 0/NaN = none): pixels where the input is far
  // behind the rendered surface (the fit overshoots onto the background) or in front of it (an
  // occluder) keep the target (ReenactmentOptions::depth_background_m / depth_occluder_m).
  // `mouth` (optional): the target actor's own open mouth, warped into the opening in place of
  // the model's teeth and the dark cavity (Sec. 7.4.1), darker as the opening narrows
  // (MouthInteriorBrightness).
  // `detail` (optional): the source actor's wrinkle-level detail (Sec. 7.3), added to the
  // re-rendered skin before the mouth interior and the blend.
  // `eyes` (optional): the actor's open eyes; with the frame texture, an eye the target holds
  // closed (eyeBlink above 0.3) and the output holds open takes its eyeball from there.
  // `openings` (optional): the target's eye openings as the frame shows them; with the frame
  // texture, an open eye whose six points lie near the fit's draws its eyeball within that
  // opening and keeps the frame's lids around it.
  CompositeResult Compose(const cv::Mat& target_bgr, const gpu::PinholeCamera& camera,
                          const gpu::FaceParameters& target, const gpu::FaceParameters& output,
                          const AlbedoMap* albedo = nullptr, const cv::Mat* target_depth = nullptr,
                          const MouthExemplar* mouth = nullptr, const DetailTransfer* detail = nullptr,
                          const EyeExemplar* eyes = nullptr, const EyeOpenings* openings = nullptr) const;

  // Takes `frame_bgr` (CV_8UC3 of camera's size) as the actor's open eyes when `params` holds
  // both eyes open (eyeBlink at most 0.15) and faces the camera (within 25 degrees): writes
  // `eyes` and returns true; else leaves it and returns false. `openings` (optional): the frame's
  // detected lid points, kept with the eyes (their eyeballs are then sampled within the real
  // openings, which a wide-eyed frame shows larger than the fit's). Throws face_reenact::Error on
  // a bad camera, frame or parameters.
  bool CaptureEyes(const cv::Mat& frame_bgr, const gpu::PinholeCamera& camera, const gpu::FaceParameters& params,
                   int64_t frame_index, EyeExemplar* eyes, const EyeOpenings* openings = nullptr) const;

  // The inner-lip polygon (iBUG 60-67, the model's landmark vertices projected) of the face at
  // `params`, in pixels; empty when the model has no such landmarks or the mouth is behind the
  // camera. The opening the mouth pass fills, and a MouthExemplar's polygon.
  std::vector<Eigen::Vector2f> MouthOpening(const gpu::PinholeCamera& camera, const gpu::FaceParameters& params) const;

  // An actor's mouth in `frame_bgr` (CV_8UC3, the camera's size) at the fit `params`, from one
  // evaluation of the model: the opening (MouthOpening's polygon) and the colour of the skin
  // around it, the per-channel median of the frame's linear colour where the face's skin
  // vertices 22-30 mm from the mouth's centre (upper lip, cheeks, chin) project, those facing
  // the camera (has_skin false when fewer than 20 of them land in the frame). What carries
  // another actor's mouth into this one's light and camera (ReenactmentOptions::source_mouth).
  struct MouthView {
    std::vector<Eigen::Vector2f> opening;
    bool has_skin = false;
    Eigen::Vector3f skin = Eigen::Vector3f::Zero();  // linear RGB
  };
  MouthView ViewMouth(const cv::Mat& frame_bgr, const gpu::PinholeCamera& camera, const gpu::FaceParameters& params) const;

  // Adds the observation of `frame_bgr` at the tracked `params` to `map` (started from the model
  // albedo of params.beta when empty): each visible, camera-facing vertex's colour divided by
  // its SH irradiance, averaged with weight cos^2(view angle) times how far the frame unfolds the
  // upper lids there (0 for the lids of open eyes: only a blink teaches their colour).
  // With `frame_depth`, vertices whose pixel's depth disagrees with the vertex by more than
  // 1.5 cm (the fit overshoots onto the background, an occluder) are not observed. With
  // `folded_lids_only`, only the lids a resting eye folds away are (a blink's frame: its fit's
  // lids meet where the real ones do not quite, and its lower lids' margins show the upper lid).
  void ObserveAlbedo(const cv::Mat& frame_bgr, const gpu::PinholeCamera& camera, const gpu::FaceParameters& params,
                     AlbedoMap* map, const cv::Mat* frame_depth = nullptr, bool folded_lids_only = false) const;

  // One view of the albedo texture (albedo_texture.h): for each texel of `layout`, the frame's
  // colour where `params` puts that surface point, divided by the shading the re-rendering gives
  // it (so the texture times the same shading gives the frame back), with a weight that is 0
  // where the frame does not show the point clearly (hidden, within
  // 2.5 px of an occluding boundary, grazing, clipped, badly lit, or an implausible colour: the
  // per-vertex map's rules, ObserveAlbedo), rises towards cos^2 of the view angle, and is taken in
  // proportion to how far the frame unfolds the upper lids there (a resting eye folds them away
  // under the brow; a blink shows them: ObserveAlbedo's rule too). With
  // `frame_depth`, only where the measured depth confirms the surface. Rasterises on the CPU and
  // changes nothing, so it may run on another thread beside Compose. Throws
  // face_reenact::Error on a bad camera or frame, or a layout of another model.
  AlbedoTextureView UnwrapAlbedo(const cv::Mat& frame_bgr, const gpu::PinholeCamera& camera,
                                 const gpu::FaceParameters& params, const AlbedoTextureLayout& layout,
                                 const cv::Mat* frame_depth = nullptr) const;

  // One frame the albedo texture is built from: the frame, its depth (may be empty), its fit.
  struct AlbedoTextureFrame {
    cv::Mat bgr, depth;
    gpu::PinholeCamera camera;
    gpu::FaceParameters params;
    int64_t frame_index = -1;
    // The closed-eyes view (AlbedoViewChooser::kClosedEyes): taken only on the lids a resting
    // eye folds away, which the resting views do not show.
    bool closed_eyes = false;
  };
  // The albedo texture of `frames` over `layout`: each unwrapped (UnwrapAlbedo), blended over the
  // per-vertex `base_albedo` (BlendAlbedoViews); build_ms is the whole. Thread-safe as UnwrapAlbedo.
  AlbedoTexture BuildAlbedoTexture(const std::vector<AlbedoTextureFrame>& frames,
                                   std::shared_ptr<const AlbedoTextureLayout> layout,
                                   const Eigen::VectorXf& base_albedo, int levels) const;

  const FaceModel& model() const;
  // "cpu", "vulkan (<device>)", or "cpu (Vulkan unavailable: <why>)" after a failed open.
  std::string renderer_description() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace face_reenact::reenact
