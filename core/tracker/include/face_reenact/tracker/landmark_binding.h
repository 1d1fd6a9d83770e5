#pragma once
// Which model vertex each of the 68 iBUG points should be bound to, measured on real video
// (`face-reenact eval bindings`): over the frames of tracked clips whose fit agrees with its
// landmarks, how far each candidate vertex near a point's current binding projects from where the
// detector puts that point, in eye distances. The binding file (data/ibug68_landmarks.json) was
// authored from the base mesh alone, and where the mesh has no feature to anchor a point (the
// brows: hm08 has no brow geometry; the nasal bridge: a ridge with no stable vertex) it was placed
// from the 300-W mean shape; this measures where real faces put those points instead. The frames
// the fit is measured on must not be a yardstick's test photos (`eval fit` scores on faces-68).
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker {

struct BindingSearchOptions {
  std::vector<int> points;        // iBUG indices to search (each needs a current binding)
  double radius_m = 0.025;        // candidates: vertices of the face part this close to the current binding (mean face)
  float min_confidence = 0.05f;   // detector points at or below this are not used
  bool IsValid(std::string* why) const;
};

class LandmarkBindingSearch {
 public:
  // `mirror_vertex`: FaceModel::mirror_vertex (the left/right partner of every vertex). A pair of
  // mirrored points is searched jointly so the binding stays mirror-consistent; a midline point
  // keeps to midline vertices. Throws face_reenact::Error on invalid options or a point the model
  // does not bind. `model` must outlive the search (it is read, not copied).
  LandmarkBindingSearch(const TrackerModel& model, std::vector<int32_t> mirror_vertex, BindingSearchOptions options);

  // One frame: its fit and the detector's points (InputFrame::landmarks). Frames without both eye
  // corners (the unit) are skipped; returns whether the frame was used.
  bool Add(const gpu::FaceParameters& fit, const gpu::PinholeCamera& camera, const std::vector<InputLandmark>& detected);

  struct Result {
    int ibug_index = 0;
    int frames = 0;
    int current_vertex = 0;    // model vertex
    double current_error = 0;  // its mean distance from the detector's point, in eye distances
    int best_vertex = 0;
    double best_error = 0;
    double best_moved_mm = 0;  // how far the best vertex lies from the current one on the mean face
  };
  std::vector<Result> Results() const;
  int frames_used() const { return frames_; }

 private:
  struct Point {
    int ibug = 0;
    int current = 0;
    std::vector<int> candidates;     // model vertices
    std::vector<double> error_sum;   // per candidate
    int frames = 0;
  };
  const TrackerModel& model_;
  std::vector<int32_t> mirror_;
  BindingSearchOptions options_;
  std::vector<Point> points_;
  int frames_ = 0;
};

nlohmann::json to_json(const std::vector<LandmarkBindingSearch::Result>& results, const std::vector<int32_t>& base_vertex);

}  // namespace face_reenact::tracker
