#pragma once
// Wrinkle-level detail transfer (paper Sec. 7.3): the folds and wrinkles an expression makes on
// the source actor's skin, which the face model cannot hold, carried onto the re-rendered target.
//
// The detail of a frame is a fine Laplacian level of its luminance, relative to the level below
// (a fold darkens the skin by a fraction, whatever the exposure). Each skin pixel of the target's
// re-rendered face names a surface point (its triangle and barycentrics); the same surface point
// on the source's fit projects into the source frame, where the detail is read. So the detail
// goes through the model's surface parametrisation and lands where it belongs on another face,
// pose and scale.
//
// Two modes:
// - kTransient (default): what the expression adds. The detail read in the current source frame
//   minus the detail at the same surface point in the source's most relaxed frame seen so far
//   (the rest frame). The target keeps its own skin (its pores, moles, the camera's grain) and
//   gains the source's folds as they appear and go.
// - kCopy: the paper's copy: the source's detail level replaces the target's on the skin, the
//   source's own skin texture included (the paper notes this looks wrong between people of
//   different skin).
// Over the UDP stream no source image exists and nothing is transferred (docs/reenactment.md).
#include <cstdint>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/model/face_model.h"

namespace face_reenact::reenact {

// One frame of the source actor as the detail transfer reads it: the image and the fit it was
// tracked with (only available where the source is tracked on this machine: a recording, a
// camera; never over the UDP stream).
struct SourceView {
  cv::Mat bgr;                 // CV_8UC3, the camera's size
  gpu::PinholeCamera camera;   // the camera the fit is in (TrackedFrame::camera)
  gpu::FaceParameters params;  // the source's fit of this frame
  int64_t frame_index = -1;    // the source's frame (reports the rest frame)
  bool IsValid(std::string* why) const;
};

enum class DetailMode { kOff, kTransient, kCopy };
const char* detail_mode_name(DetailMode mode);  // "off", "transient", "copy"
bool ParseDetailMode(const std::string& name, DetailMode* mode);

struct DetailTransferOptions {
  DetailMode mode = DetailMode::kTransient;
  // The transferred relative change is multiplied by this ([0, 4]).
  float gain = 1.0f;
  // kTransient: a change of relative contrast smaller than this is noise (a tracking error of a
  // pixel moves the skin's own texture by about that much) and is dropped; larger ones are
  // shrunk by it (soft threshold).
  float coring = 0.012f;
  // No pixel is darkened or brightened by more than this fraction ((0, 1]).
  float max_contrast = 0.35f;
  // The rest frame faces the camera within this many degrees.
  float rest_max_turn_deg = 20.f;
  bool IsValid(std::string* why) const;
};

// What one Apply did.
struct DetailStats {
  int pixels = 0;            // target pixels whose colour changed
  int level = -1;            // the source's Laplacian level read (0 = finest; chosen by scale)
  float mean_change = 0.f;   // mean |relative change| over the changed pixels
  double ms = 0.0;
};

class DetailTransfer {
 public:
  // Throws face_reenact::Error on invalid options, or a model without the landmarks that mark
  // the lips and the eyes (the detail is kept off them: their edges are not skin detail).
  DetailTransfer(const FaceModel& model, const DetailTransferOptions& options);
  ~DetailTransfer();
  DetailTransfer(const DetailTransfer&) = delete;
  DetailTransfer& operator=(const DetailTransfer&) = delete;

  void SetOptions(const DetailTransferOptions& options);  // throws on invalid options
  const DetailTransferOptions& options() const;

  // The source's newest frame and fit. In kTransient it also becomes the rest frame when it
  // faces the camera and its expression is clearly more relaxed than the rest frame's (the
  // first such frame starts it). `strength` in [0, 1]: how much of the source's expression the
  // output shows (SourceExpression::blend_weight). Throws face_reenact::Error on an invalid view.
  void Observe(const SourceView& view, float strength = 1.0f);
  // Forgets the source's frames (a new source actor).
  void Reset();

  // Whether Apply has a source frame to read (and, in kTransient, a rest frame).
  bool ready() const;
  int64_t rest_frame_index() const;  // -1: none yet
  // "off", "none yet: ...", or what is transferred and from which rest frame.
  std::string Description() const;

  // Changes the colour of the target's re-rendered skin pixels: `g` is the output face's G-buffer
  // through `camera` (the target's), `drawn` (CV_8UC1, the G-buffer's size) marks the pixels the
  // face layer owns, `rendered` (CV_32FC3, BGR sRGB 0..255) holds their colour. Pixels whose
  // surface point the source frame does not show (hidden, grazing, outside the frame) keep their
  // colour. A no-op when !ready() or the mode is kOff. Throws face_reenact::Error on mismatched
  // buffers.
  DetailStats Apply(const gpu::GBuffer& g, const gpu::PinholeCamera& camera, const cv::Mat& drawn,
                    cv::Mat* rendered) const;

  // Per model vertex, how much detail the surface there takes (0 on the lips, the eyes and
  // nostrils and off the face part, 1 on the skin, smooth in between): for tests.
  const std::vector<float>& skin_weight() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace face_reenact::reenact
