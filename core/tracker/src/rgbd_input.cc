#include "face_reenact/tracker/rgbd_input.h"

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <limits>
#include <utility>

#include "face_reenact/common/error.h"
#include "face_reenact/common/srgb.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
using internal::Clock;
using internal::kRadToDeg;

bool RgbdInputOptions::IsValid(std::string* why) const {
  if (!(stored_landmark_confidence > 0.f && stored_landmark_confidence <= 1.f)) {
    return fail_why(why, "input: stored_landmark_confidence must be in (0, 1]");
  }
  if (!(detector_confidence_scale > 0.f && detector_confidence_scale <= 1.f)) {
    return fail_why(why, "input: detector_confidence_scale must be in (0, 1]");
  }
  if (landmark_source == LandmarkSourceChoice::kDetector) {
    std::string inner;
    if (!detector.IsValid(&inner)) return fail_why(why, "input: landmark detector: " + inner);
  }
  return true;
}

InputFrame MakeInputFrameNoLandmarks(const capture::RgbdFrame& frame, bool use_depth, InputFrame* reuse) {
  InputFrame in;
  if (reuse) {
    in.color = std::move(reuse->color);
    in.depth = std::move(reuse->depth);
    in.depth.clear();  // (its capacity kept: this frame may have none)
  }
  in.camera = frame.camera;
  in.timestamp_s = std::isfinite(frame.timestamp_s) ? frame.timestamp_s : std::numeric_limits<double>::quiet_NaN();
  std::string why;
  if (!in.camera.IsValid(&why)) throw Error("frame " + std::to_string(frame.index) + ": " + why);
  const int w = in.camera.width, h = in.camera.height;
  if (frame.color.type() != CV_8UC3 || frame.color.cols != w || frame.color.rows != h) {
    throw Error("frame " + std::to_string(frame.index) + ": colour image must be 8-bit BGR of the camera's size " +
                std::to_string(w) + "x" + std::to_string(h));
  }
  const auto& table = srgb_decode_table();
  in.color.resize(static_cast<size_t>(w) * h * 3);  // a reused buffer of this size as it is: written in full
  for (int j = 0; j < h; ++j) {
    const uint8_t* row = frame.color.ptr<uint8_t>(j);
    float* dst = &in.color[static_cast<size_t>(j) * w * 3];
    for (int i = 0; i < w; ++i) {
      dst[3 * i + 0] = table[row[3 * i + 2]];  // BGR -> RGB
      dst[3 * i + 1] = table[row[3 * i + 1]];
      dst[3 * i + 2] = table[row[3 * i + 0]];
    }
  }
  if (use_depth && !frame.depth.empty()) {
    if (frame.depth.type() != CV_32FC1 || frame.depth.cols != w || frame.depth.rows != h) {
      throw Error("frame " + std::to_string(frame.index) + ": depth image must be 32-bit float metres of the camera's size");
    }
    in.depth.resize(static_cast<size_t>(w) * h);
    for (int j = 0; j < h; ++j) {
      const float* row = frame.depth.ptr<float>(j);
      for (int i = 0; i < w; ++i) {
        const float d = row[i];
        // 0, NaN, infinities and negative values all mean "no measurement" (InputFrame keeps 0).
        in.depth[static_cast<size_t>(j) * w + i] = std::isfinite(d) && d > 0.f ? d : 0.f;
      }
    }
  }
  return in;
}

std::vector<InputLandmark> StoredLandmarks(const capture::RgbdFrame& frame, float confidence) {
  std::vector<InputLandmark> out;
  if (!frame.ground_truth.landmarks) return out;
  const auto& lms = *frame.ground_truth.landmarks;
  for (int k = 0; k < capture::kNumLandmarks; ++k) {
    if (!lms[k].pixel.allFinite()) continue;
    InputLandmark l;
    l.ibug_index = k;
    l.position = lms[k].pixel;
    l.confidence = lms[k].visible ? confidence : 0.f;
    out.push_back(l);
  }
  return out;
}

std::vector<InputLandmark> DetectedLandmarks(const landmarks::LandmarkResult& result, float scale) {
  std::vector<InputLandmark> out;
  if (!result.has_landmarks) return out;
  for (int k = 0; k < landmarks::kNumLandmarks; ++k) {
    if (!result.points[k].allFinite()) continue;
    InputLandmark l;
    l.ibug_index = k;
    l.position = result.points[k];
    const float c = result.confidence[k];
    l.confidence = result.visible[k] && std::isfinite(c) && c > 0.f ? c * scale : 0.f;
    out.push_back(l);
  }
  return out;
}

landmarks::HeadPose HeadPoseFromParameters(const gpu::FaceParameters& params) {
  const Eigen::Matrix3f r = gpu::rotation_from_euler(params.euler);
  const Eigen::Vector3f nose = r * Eigen::Vector3f::UnitZ();  // model +z: out of the face
  const Eigen::Vector3f up = r * Eigen::Vector3f::UnitY();    // model +y: up the face
  landmarks::HeadPose pose;
  // Facing the camera the nose points along -z; yaw turns it toward +x, pitch (chin down)
  // toward +y (image down); roll turns the face's up vector (image -y) clockwise, toward +x.
  pose.yaw_deg = static_cast<float>(std::atan2(nose.x(), -nose.z()) * kRadToDeg);
  pose.pitch_deg = static_cast<float>(std::atan2(nose.y(), std::hypot(nose.x(), nose.z())) * kRadToDeg);
  pose.roll_deg = static_cast<float>(std::atan2(up.x(), -up.y()) * kRadToDeg);
  return pose;
}

InputFrame MakeInputFrame(const capture::RgbdFrame& frame, const RgbdInputOptions& options,
                          landmarks::LandmarkTracker* detector, RgbdInputInfo* info, const landmarks::HeadPose* pose,
                          InputFrame* reuse) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  RgbdInputInfo local;
  RgbdInputInfo& inf = info ? *info : local;
  inf = RgbdInputInfo();
  const auto t0 = Clock::now();
  InputFrame in = MakeInputFrameNoLandmarks(frame, options.use_depth, reuse);
  inf.conversion_ms = ms_since(t0);
  inf.depth_used = in.has_depth();
  if (options.landmark_source == LandmarkSourceChoice::kRecording) {
    in.landmarks = StoredLandmarks(frame, options.stored_landmark_confidence);
    inf.landmark_status = in.landmarks.empty() ? "no stored landmarks" : "ok";
  } else {
    if (!detector) throw Error("input: the landmark source is the detector but no landmark tracker was given");
    const auto t1 = Clock::now();
    const landmarks::ImageView view{frame.color.data, frame.color.cols, frame.color.rows, frame.color.step[0],
                                    landmarks::PixelFormat::kBGR8};
    const landmarks::LandmarkResult result = detector->Track(view, frame.timestamp_s, pose);
    inf.landmarks_ms = ms_since(t1);
    in.landmarks = DetectedLandmarks(result, options.detector_confidence_scale);
    in.new_face = result.switched_face;
    inf.landmark_status = result.ok() ? "ok" : std::string(landmarks::status_name(result.status)) + ": " + result.reason;
  }
  for (const auto& l : in.landmarks) inf.landmarks += l.confidence > 0.f;
  return in;
}

void PreloadLandmarkModel(const RgbdInputOptions& options) {
  if (options.landmark_source == LandmarkSourceChoice::kDetector)
    landmarks::PreloadShapeModel(options.detector.detector);
}

RgbdInput::RgbdInput(const RgbdInputOptions& options) : options_(options) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error(why);
  if (options_.landmark_source == LandmarkSourceChoice::kDetector) {
    detector_ = std::make_unique<landmarks::LandmarkTracker>(options_.detector);
  }
}

RgbdInput::~RgbdInput() = default;
RgbdInput::RgbdInput(RgbdInput&&) noexcept = default;
RgbdInput& RgbdInput::operator=(RgbdInput&&) noexcept = default;

InputFrame RgbdInput::Convert(const capture::RgbdFrame& frame, RgbdInputInfo* info) {
  InputFrame reuse;
  {
    std::lock_guard lock(*spare_mu_);
    reuse = std::exchange(spare_, InputFrame());
  }
  return MakeInputFrame(frame, options_, detector_.get(), info, have_pose_ ? &pose_ : nullptr, &reuse);
}

void RgbdInput::Recycle(InputFrame&& frame) {
  std::lock_guard lock(*spare_mu_);
  spare_ = std::move(frame);
}

void RgbdInput::SetTrackedPose(const gpu::FaceParameters& params, bool has_fit) {
  have_pose_ = has_fit && params.euler.allFinite();
  if (have_pose_) pose_ = HeadPoseFromParameters(params);
}

void RgbdInput::Reset() {
  if (detector_) detector_->Reset();
  have_pose_ = false;
}

}  // namespace face_reenact::tracker
