#pragma once
// The tracker's fit drawn over the frame it was fitted to, so that a person sees at a glance
// whether it sits on the face (`track --overlay`, the live sessions' overlay mode): the visible
// edges of the fitted mesh (the face brighter than scalp, ears and neck), the detector's
// landmarks (green) and the fit's own (red; a red dot beside its green one is a disagreement),
// and a status line with the frame's agreement figures (fit_agreement.h).
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::reenact {

struct FitOverlayOptions {
  bool mesh = true;             // the visible triangles' edges
  bool landmarks = true;        // detector (green) and fit (red) landmarks
  // In (0, 1]: how strongly the edges cover the frame. A 640x480 face has a few thousand visible
  // edges, so the skin shows through only when they are faint.
  float mesh_opacity = 0.3f;
  float min_landmark_confidence = 0.05f;
  bool IsValid(std::string* why) const;
};

// Draws onto `bgr` (CV_8UC3 of the camera's size). `params` may be null (no fit: only the
// detector's landmarks and the status). `status` is printed in the top-left corner when not
// empty. Throws face_reenact::Error on a wrong-sized image or invalid options.
void DrawFitOverlay(cv::Mat* bgr, const tracker::TrackerModel& model, const gpu::CpuRenderer& renderer,
                    const gpu::PinholeCamera& camera, const gpu::FaceParameters* params,
                    const std::vector<tracker::InputLandmark>& detected, const std::string& status,
                    const FitOverlayOptions& options = {});

// The status line of a tracked frame for the overlay: "tracking | pose 2.7 deg off | points 4.2%
// of eye dist." (the pose against the landmarks' pose, the inner points against the detector's).
std::string OverlayStatusLine(const std::string& status, double pose_disagreement_deg, double landmark_nme);

}  // namespace face_reenact::reenact
