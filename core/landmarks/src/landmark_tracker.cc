#include "face_reenact/landmarks/landmark_tracker.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "face_reenact/common/error.h"
#include "landmark_internal.h"

namespace face_reenact::landmarks {

bool TrackerOptions::IsValid(std::string* error) const {
  if (!detector.IsValid(error) || !smoothing.IsValid(error)) return false;
  auto fail = [&](const std::string& m) {
    if (error) *error = "landmark tracker options: " + m;
    return false;
  };
  if (redetect_interval < 0) return fail("redetect_interval must be >= 0");
  if (reacquire_frames < 0) return fail("reacquire_frames must be >= 0");
  if (!(redetect_band >= 0.f && redetect_band <= 4.f)) return fail("redetect_band must be in [0, 4]");
  if (prominent_face_interval < 0) return fail("prominent_face_interval must be >= 0");
  if (!(prominent_face_max_width >= 0.f && prominent_face_max_width <= 1.f))
    return fail("prominent_face_max_width must be in [0, 1]");
  if (!(prominent_face_area_ratio >= 1.f && prominent_face_area_ratio <= 100.f))
    return fail("prominent_face_area_ratio must be in [1, 100]");
  if (!(start_box_deadband >= 0.f && start_box_deadband <= 0.5f)) return fail("start_box_deadband must be in [0, 0.5]");
  if (!(min_track_confidence >= 0.f && min_track_confidence < 1.f)) {
    return fail("min_track_confidence must be in [0, 1)");
  }
  return true;
}

std::string TrackerSummary::BriefReport() const {
  std::ostringstream s;
  s << frames << " frames, " << frames_with_landmarks << " with landmarks; " << tracked_frames << " tracked, "
    << full_searches << " full searches, " << band_searches << " band searches (" << band_misses << " missed), "
    << losses << " losses";
  if (face_switches > 0) s << ", " << face_switches << " switches to a more prominent face";
  if (!last_loss_reason.empty()) s << " (last: " << last_loss_reason << ")";
  return s.str();
}

struct LandmarkTracker::Impl {
  TrackerOptions options;
  LandmarkDetector detector;
  LandmarkSmoother smoother;
  TrackerSummary summary;
  bool tracking = false;
  Shape68 previous_points{};
  Box previous_box;
  bool has_previous_box = false;
  int frames_since_search = 0;
  int frames_without_followed_face = 0;
  int frames_since_prominent_search = 0;
  Box last_start_box;
  bool has_start_box = false;
  float anchor_scale = 1.f;
  Eigen::Vector2f anchor_offset = Eigen::Vector2f::Zero();

  explicit Impl(const TrackerOptions& o) : options(o), detector(o.detector), smoother(o.smoothing) {}

  // Why a tracked fit is not the face any more ("" while it is).
  std::string loss_reason(const LandmarkResult& r, int width, int height) const {
    const DetectorOptions& d = options.detector;
    char buf[128];
    if (r.shape_residual > d.max_shape_residual) {
      std::snprintf(buf, sizeof(buf), "implausible shape (residual %.3f)", double(r.shape_residual));
      return buf;
    }
    float mean_conf = 0;
    for (float c : r.confidence) mean_conf += c;
    mean_conf /= kNumLandmarks;
    if (mean_conf < options.min_track_confidence) {
      std::snprintf(buf, sizeof(buf), "low confidence (%.2f)", double(mean_conf));
      return buf;
    }
    if (r.face_box.fraction_outside(width, height) > 0.5f) return "face left the frame";
    if (r.face_box.width < 0.5f * float(d.min_face_size)) return "face became too small";
    return "";
  }

  LandmarkResult full_search(const ImageView& gray_view) {
    ++summary.full_searches;
    frames_since_search = 0;
    LandmarkResult r;
    if (!has_previous_box) {
      r = detector.Detect(gray_view);
    } else {
      r = search_for_followed_face(gray_view);
    }
    // A different face (or the first one) starts a new filter history; re-finding the same
    // face keeps it, so detect-every-frame mode can be smoothed too.
    if (!(r.has_landmarks && has_previous_box && r.face_box.iou(previous_box) > 0.3f)) smoother.Reset();
    return r;
  }

  // The start box for a tracked frame: BoxFromPoints of the previous points, held still while
  // it stays inside the deadband of the last start box.
  Box start_box() {
    Box fresh = detector.BoxFromPoints(previous_points);
    // Re-centre in the detector's own convention for this face (see anchor_to_detection).
    const float w = fresh.width * anchor_scale;
    const Eigen::Vector2f c = fresh.center() + fresh.width * anchor_offset;
    fresh = Box{c.x() - 0.5f * w, c.y() - 0.5f * w, w, w};
    if (has_start_box) {
      const float size = std::max(1.f, last_start_box.width);
      const float moved = (fresh.center() - last_start_box.center()).norm() / size;
      const float scaled = std::abs(fresh.width / size - 1.f);
      if (moved < options.start_box_deadband && scaled < options.start_box_deadband) return last_start_box;
    }
    last_start_box = fresh;
    has_start_box = true;
    return fresh;
  }

  // How the detector's box for this face sits relative to BoxFromPoints of its landmarks
  // (offset in box widths, scale). It varies by up to ~15% between faces; keeping it per track
  // makes a tracked frame start where a detection on that frame would have started.
  void anchor_to_detection(const LandmarkResult& r) {
    const Box fit = detector.BoxFromPoints(r.points);
    if (!(fit.width > 1.f) || !(r.face_box.width > 1.f)) return;
    const float scale = r.face_box.width / fit.width;
    const Eigen::Vector2f offset = (r.face_box.center() - fit.center()) / fit.width;
    if (!std::isfinite(scale) || !offset.allFinite() || scale < 0.7f || scale > 1.4f || offset.norm() > 0.25f) {
      anchor_scale = 1.f;
      anchor_offset.setZero();
      return;
    }
    anchor_scale = scale;
    anchor_offset = offset;
  }

  // A search that prefers the face we followed; within reacquire_frames of losing it, other
  // faces are ignored so a blur or a turn of the followed person does not switch people.
  LandmarkResult search_for_followed_face(const ImageView& gray_view) {
    LandmarkResult r;
    const DetectorOptions& d = options.detector;
    if (gray_view.width < d.min_face_size || gray_view.height < d.min_face_size) return detector.Detect(gray_view);
    const std::vector<FaceCandidate> faces = detector.FindFaces(gray_view, /*harder=*/true, previous_box);
    int best = -1;
    float best_iou = 0.2f;
    for (size_t i = 0; i < faces.size(); ++i) {
      const float iou = faces[i].box.iou(previous_box);
      if (iou > best_iou) {
        best_iou = iou;
        best = int(i);
      }
    }
    if (best < 0 && frames_without_followed_face < options.reacquire_frames) {
      ++frames_without_followed_face;
      r.status = DetectionStatus::kNoFace;
      r.reason = "lost the followed face; waiting for it to return (" + std::to_string(frames_without_followed_face) +
                 "/" + std::to_string(options.reacquire_frames) + " frames, " + std::to_string(faces.size()) +
                 " other faces seen)";
      r.faces_found = int(faces.size());
      return r;
    }
    if (best < 0) {
      if (faces.empty()) {
        r.status = DetectionStatus::kNoFace;
        r.reason = "no face found";
        return r;
      }
      best = 0;
      for (size_t i = 1; i < faces.size(); ++i) {
        if (faces[i].box.area() > faces[size_t(best)].box.area()) best = int(i);
      }
      has_previous_box = false;  // a new person: their track starts here
    }
    frames_without_followed_face = 0;
    r = detector.FitFromBox(gray_view, faces[size_t(best)].box);
    r.source = LandmarkSource::kDetected;
    r.detector_score = faces[size_t(best)].score;
    r.faces_found = int(faces.size());
    return r;
  }

  // TrackerOptions::prominent_face_*: while the followed face is small, look for a much larger
  // face elsewhere every prominent_face_interval frames. Returns true (and fills *r) on a switch.
  bool switch_to_prominent_face(const ImageView& gray_view, LandmarkResult* r) {
    if (options.prominent_face_interval <= 0 ||
        previous_box.width >= options.prominent_face_max_width * float(gray_view.width))
      return false;
    if (++frames_since_prominent_search < options.prominent_face_interval) return false;
    frames_since_prominent_search = 0;
    ++summary.prominent_searches;
    const std::vector<FaceCandidate> faces = detector.FindFaces(gray_view, /*harder=*/false);
    int best = -1;
    float best_area = options.prominent_face_area_ratio * previous_box.area();
    for (size_t i = 0; i < faces.size(); ++i) {
      // Overlapping the followed face: that face itself (nearer, or its box drawn differently).
      if (faces[i].box.iou(previous_box) > 0.f) continue;
      if (faces[i].box.area() >= best_area) {
        best_area = faces[i].box.area();
        best = int(i);
      }
    }
    if (best < 0) return false;
    LandmarkResult candidate = detector.FitFromBox(gray_view, faces[size_t(best)].box);
    // A detection the shape predictor cannot fit as a face is not worth leaving the track for.
    if (!candidate.has_landmarks || !loss_reason(candidate, gray_view.width, gray_view.height).empty()) return false;
    candidate.source = LandmarkSource::kDetected;
    candidate.detector_score = faces[size_t(best)].score;
    candidate.faces_found = int(faces.size());
    candidate.switched_face = true;
    ++summary.face_switches;
    smoother.Reset();  // another face: its own filter history
    *r = std::move(candidate);
    return true;
  }

  LandmarkResult track(const ImageView& frame, double timestamp_s, const HeadPose* pose) {
    ++summary.frames;
    LandmarkResult r;
    std::string error;
    if (!frame.IsValid(&error)) {
      r.status = DetectionStatus::kInvalidInput;
      r.reason = error;
      return r;
    }
    // One grey conversion per frame; every later step gets the zero-copy grey view.
    const cv::Mat gray = internal::to_gray(frame);
    const ImageView gray_view{gray.data, gray.cols, gray.rows, gray.step[0], PixelFormat::kGray8};

    if (options.detect_every_frame || !tracking) {
      r = full_search(gray_view);
    } else {
      ++frames_since_search;
      bool fitted = switch_to_prominent_face(gray_view, &r);
      if (!fitted && options.redetect_interval > 0 && frames_since_search >= options.redetect_interval) {
        frames_since_search = 0;
        ++summary.band_searches;
        const float g = options.redetect_band;
        const Box band{previous_box.x - g * previous_box.width, previous_box.y - g * previous_box.height,
                       previous_box.width * (1 + 2 * g), previous_box.height * (1 + 2 * g)};
        const std::vector<FaceCandidate> faces = detector.FindFacesInRegion(gray_view, band, previous_box.width);
        int best = -1;
        float best_iou = 0.3f;
        for (size_t i = 0; i < faces.size(); ++i) {
          const float iou = faces[i].box.iou(previous_box);
          if (iou > best_iou) {
            best_iou = iou;
            best = int(i);
          }
        }
        if (best >= 0) {
          // Re-anchor on the detector's box: corrects any slow drift of the tracked start box.
          r = detector.FitFromBox(gray_view, faces[size_t(best)].box);
          r.source = LandmarkSource::kDetected;
          r.detector_score = faces[size_t(best)].score;
          r.faces_found = int(faces.size());
          fitted = true;
        } else {
          ++summary.band_misses;
        }
      }
      if (!fitted) r = detector.FitFromBox(gray_view, start_box());
      const std::string why = loss_reason(r, gray.cols, gray.rows);
      if (!why.empty()) {
        ++summary.losses;
        summary.last_loss_reason = why;
        tracking = false;
        r = full_search(gray_view);
      } else if (r.source == LandmarkSource::kTracked) {
        ++summary.tracked_frames;
      }
    }

    if (r.source != LandmarkSource::kTracked) {
      has_start_box = false;  // new anchor from a search
      if (r.has_landmarks) anchor_to_detection(r);
    }
    if (r.has_landmarks && r.status != DetectionStatus::kNoFace && r.status != DetectionStatus::kInvalidInput &&
        loss_reason(r, gray.cols, gray.rows).empty()) {
      tracking = true;
      previous_points = r.points;  // unsmoothed: the next start box must not lag
      previous_box = r.face_box;
      has_previous_box = true;
    } else {
      tracking = false;
    }
    if (r.has_landmarks) {
      ++summary.frames_with_landmarks;
      if (pose) apply_pose_pruning(*pose, options.detector, &r);
      smoother.Apply(timestamp_s, &r.points);
    }
    return r;
  }
};

LandmarkTracker::LandmarkTracker(const TrackerOptions& options) {
  std::string error;
  if (!options.IsValid(&error)) throw Error(error);
  impl_ = std::make_unique<Impl>(options);
}
LandmarkTracker::~LandmarkTracker() = default;
LandmarkTracker::LandmarkTracker(LandmarkTracker&&) noexcept = default;
LandmarkTracker& LandmarkTracker::operator=(LandmarkTracker&&) noexcept = default;

LandmarkResult LandmarkTracker::Track(const ImageView& frame, double timestamp_s, const HeadPose* pose) {
  return impl_->track(frame, timestamp_s, pose);
}

void LandmarkTracker::Reset() {
  impl_->tracking = false;
  impl_->has_previous_box = false;
  impl_->frames_since_search = 0;
  impl_->frames_without_followed_face = 0;
  impl_->frames_since_prominent_search = 0;
  impl_->has_start_box = false;
  impl_->smoother.Reset();
}

bool LandmarkTracker::tracking() const { return impl_->tracking; }
const TrackerSummary& LandmarkTracker::summary() const { return impl_->summary; }
const TrackerOptions& LandmarkTracker::options() const { return impl_->options; }

}  // namespace face_reenact::landmarks
