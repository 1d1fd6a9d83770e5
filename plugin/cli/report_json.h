#pragma once
// Report sections that several commands write (`track --report`, `reenact --report`): one
// wording of each yardstick.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "face_reenact/capture/recording.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/fit_agreement.h"

namespace face_reenact::cli {

// Which intrinsics an input's frames carry, for the reports: a recording's own, an OpenNI device's,
// or, for a video file or a webcam, the pinhole of the report's camera section (camera_options.h:
// estimated, given or assumed).
inline std::string intrinsics_description(const std::string& input, const capture::RecordingInfo& info,
                                          const nlohmann::json& camera) {
  std::error_code ec;
  if (std::filesystem::is_directory(input, ec)) return "recording";
  if (info.source.rfind("OpenNI", 0) == 0) return "the device's (" + info.source + ")";
  char fov[32];
  std::snprintf(fov, sizeof(fov), "%.1f", camera["horizontal_fov_deg"].get<double>());
  return std::string("principal point at the centre, ") + fov + " degrees horizontal field of view (" +
         camera["from"].get<std::string>() + ")";
}

// The calibration again on the most relaxed frames after one not at rest
// (FaceTracker::relaxed_recalibration()): null when no watch was needed.
inline nlohmann::json relaxed_recalibration_json(const tracker::FaceTracker::RelaxedRecalibration& r) {
  if (!r.searched) return nlohmann::json();
  return {{"recalibrated", r.recalibrated}, {"first_weight", r.first_weight}, {"relaxed_weight", r.relaxed_weight},
          {"frames", r.frame_indices},      {"message", r.message}};
}

// The report's "agreement" section (FitAgreementTally::Summary).
inline nlohmann::json agreement_json(const tracker::FitAgreementTally::Summary& s) {
  auto dist = [](const tracker::Distribution& d) { return tracker::to_json(d); };
  nlohmann::json listed = nlohmann::json::array();
  for (const auto& b : s.beyond) listed.push_back({{"frame", b.frame}, {"what", b.what}, {"value", b.value}, {"message", b.message}});
  return {{"limits", {{"pose_disagreement_deg", s.yardstick.max_pose_disagreement_deg},
                      {"landmark_nme", s.yardstick.max_landmark_nme},
                      {"rotation_speed_deg_s", s.yardstick.max_rotation_speed_deg_s}}},
          {"fit_frames", s.fit_frames},
          {"pose_disagreement_deg", dist(s.pose_disagreement_deg)},
          {"landmark_nme", dist(s.landmark_nme)},
          {"rotation_speed_deg_s", dist(s.rotation_speed_deg_s)},
          {"landmark_nme_by_part", {{"brows", dist(s.nme_brows)}, {"nose", dist(s.nme_nose)},
                                    {"eyes", dist(s.nme_eyes)}, {"mouth", dist(s.nme_mouth)}}},
          {"fit_frames_beyond", {{"pose", s.beyond_pose}, {"landmarks", s.beyond_landmarks},
                                 {"rotation_speed", s.beyond_rotation_speed}}},
          {"beyond", listed},
          {"refused_frames", s.refused_frames}};
}

// The report's "light" section (LightProjectionTally).
inline nlohmann::json light_json(const tracker::LightProjectionTally& t) {
  return {{"fit_frames", t.frames},
          {"projected_frames", t.projected},
          {"projected_moved_mean", t.moved_mean()},
          {"projected_moved_max", t.moved_max},
          {"what", "frames whose fitted light no room gives (plausible_light.h), moved to the nearest one that is"}};
}

}  // namespace face_reenact::cli
