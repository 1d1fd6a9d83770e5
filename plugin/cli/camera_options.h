#pragma once
// The camera options of `track` and `reenact` (--fov, --intrinsics) and the report's camera
// section: which intrinsics the fits used and where they came from (issue #26 §5). Without either
// option a video file's or a webcam's focal length is estimated by the tracker during calibration
// (tracker/focal_length.h); with one, nothing is estimated.
#include <cmath>
#include <cstdio>
#include <sstream>
#include <string>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "face_reenact/capture/recording.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/json_number.h"
#include "face_reenact/tracker/face_tracker.h"

namespace face_reenact::cli {

struct CameraArgs {
  double fov_deg = 0;      // 0: not given
  std::string intrinsics;  // "fx,fy,cx,cy" or empty
  bool given() const { return fov_deg > 0 || !intrinsics.empty(); }
};

inline void add_camera_options(CLI::App* command, CameraArgs* args) {
  auto* fov = command->add_option("--fov", args->fov_deg,
                                  "Horizontal field of view (degrees) of video files and webcams; default: estimated "
                                  "from the face during calibration (60 when that cannot decide)")
                  ->check(CLI::Range(10.0, 170.0));
  command->add_option("--intrinsics", args->intrinsics, "fx,fy,cx,cy (pixels) of video files; no estimate then")
      ->excludes(fov);
}

// A video file's camera from the options (the 60 degrees assumed until the tracker's estimate when
// neither is given).
inline capture::VideoReader::Options video_options(const CameraArgs& a, const std::string& command) {
  capture::VideoReader::Options vo;
  if (a.fov_deg > 0) vo.horizontal_fov_deg = a.fov_deg;
  if (!a.intrinsics.empty()) {
    capture::VideoReader::Intrinsics k;
    char tail = 0;
    if (std::sscanf(a.intrinsics.c_str(), "%lf,%lf,%lf,%lf%c", &k.fx, &k.fy, &k.cx, &k.cy, &tail) != 4 || !(k.fx > 0) ||
        !(k.fy > 0) || !std::isfinite(k.fx) || !std::isfinite(k.fy) || !std::isfinite(k.cx) || !std::isfinite(k.cy))
      throw Error(command + ": --intrinsics must be fx,fy,cx,cy in pixels with fx, fy > 0 (got '" + a.intrinsics + "')");
    vo.intrinsics = k;
  }
  return vo;
}

// Whether an input's camera is an assumption the tracker should replace by its estimate: a video
// file or a V4L2 camera, and no --fov / --intrinsics.
inline bool camera_is_assumed(const capture::RecordingInfo& info) {
  return !info.has_depth && (info.generator == "video file" || info.source.rfind("camera", 0) == 0);
}
inline bool estimate_focal_length(const CameraArgs& a, const capture::RecordingInfo& info) {
  return !a.given() && camera_is_assumed(info);
}

// The report's camera section: the intrinsics the fits used after calibration, where they came
// from ("recording", "device", "--fov", "--intrinsics", "estimated", "fallback", "assumed"), and the
// focal length search when one ran.
inline nlohmann::json camera_json(const capture::RecordingInfo& info, const CameraArgs& a,
                                  const tracker::FaceTracker::FocalLengthReport& focal) {
  gpu::PinholeCamera c = info.camera;
  std::string from;
  if (!camera_is_assumed(info)) {
    from = info.source.rfind("OpenNI", 0) == 0 ? "device" : "recording";
  } else if (!a.intrinsics.empty()) {
    from = "--intrinsics";
  } else if (a.fov_deg > 0) {
    from = "--fov";
  } else if (focal.searched) {
    from = focal.estimate.estimated ? "estimated" : "fallback";
    c = tracker::WithHorizontalFov(c, focal.estimate.horizontal_fov_deg);
  } else {
    from = "assumed";  // no calibration happened (no face): the reader's 60 degrees
  }
  nlohmann::json j = {{"fx", c.fx}, {"fy", c.fy}, {"cx", c.cx}, {"cy", c.cy}, {"width", c.width}, {"height", c.height},
                      {"horizontal_fov_deg", tracker::HorizontalFovDeg(c)}, {"from", from}};
  if (focal.searched) {
    const tracker::FocalLengthEstimate& e = focal.estimate;
    nlohmann::json grid = nlohmann::json::array();
    for (const auto& [fov, energy] : e.energy_by_fov) grid.push_back({fov, json_number(energy)});
    j["focal_length_search"] = {{"estimated", e.estimated},   {"horizontal_fov_deg", e.horizontal_fov_deg},
                                {"energy", json_number(e.energy)}, {"landmark_rms_px", json_number(e.landmark_error_px)},
                                {"frames", e.frames},         {"ms", e.ms},
                                {"message", e.message},       {"energy_by_fov", grid}};
    // The fields of view the landmarks fit within their noise (null where the search stopped before).
    j["focal_length_search"]["fov_interval_deg"] =
        e.fov_high_deg > 0 ? nlohmann::json::array({e.fov_low_deg, e.fov_high_deg}) : nlohmann::json();
  }
  return j;
}

// One line for the summaries: "camera: 71.3 degrees horizontal (estimated: ...)".
inline std::string camera_line(const nlohmann::json& camera) {
  char buf[160];
  std::snprintf(buf, sizeof(buf), "camera: %.1f degrees horizontal, fx %.1f (%s)", camera["horizontal_fov_deg"].get<double>(),
                camera["fx"].get<double>(), camera["from"].get<std::string>().c_str());
  std::string line = buf;
  if (camera.contains("focal_length_search")) line += ": " + camera["focal_length_search"]["message"].get<std::string>();
  return line;
}

}  // namespace face_reenact::cli
