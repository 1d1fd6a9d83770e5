#pragma once
// Eyeball surface the frame does not show, completed from the surface it does show (internal to
// fr_reenact; the compositor's frame texture, face_compositor.cc).
//
// An eyeball is a sphere with a pattern about its axis (pupil, iris, sclera): a place on it is
// its direction from the eyeball's centre in the model's rest shape (+z the axis, +y up), which
// stays on the surface however the gaze turns it. The output bares eyeball the frame hides when
// it opens an eye wider than the target's (the iris' top and the white above it, under the
// target's upper lid) or turns it further; filled by the pixels around in the image, that drew
// the iris' grey into the white and the model's white beside it, hard-edged bands across the eye
// (d6 wide-eyed onto d10, output frames 116-119). Filled by place on the eyeball instead, an iris
// stays an iris and the white stays white: first the frame's samples of the same place nearby
// (a pixel the boundary rules distrust), then the mirror place across the horizontal meridian
// (the iris' bottom for its top: the lids hide opposite ends), then the same angle from the axis
// anywhere (a ring: the iris and the white are rings), then `fallback`.
#include <vector>

#include <Eigen/Core>

namespace face_reenact::reenact::internal {

class EyeballFill {
 public:
  // `radius_px`: the eyeball's radius in the output's pixels; the kernels are a pixel or two.
  explicit EyeballFill(float radius_px);

  // A frame sample at place `direction` (unit), trusted `weight` (0..1). Samples trusted less
  // than half fill nothing while the eye has enough trusted ones.
  void Add(const Eigen::Vector3f& direction, const Eigen::Vector3f& colour, float weight);

  // The colour at place `direction` from the samples, `fallback` where none is near.
  Eigen::Vector3f At(const Eigen::Vector3f& direction, const Eigen::Vector3f& fallback) const;

  bool empty() const { return samples_.empty(); }

 private:
  struct Sample {
    Eigen::Vector3f direction, colour;
    float weight;
    float angle;  // from the axis (radians), for the ring
  };
  // The samples' weighted mean within the kernel around `direction` (or, with `ring`, at its angle
  // from the axis), and how sure it is (0..1: the share of a full neighbourhood's weight).
  float Mean(const Eigen::Vector3f& direction, bool ring, Eigen::Vector3f* mean) const;

  float radius_px_;
  std::vector<Sample> samples_;
  int trusted_ = 0;  // samples of weight >= kTrusted (eyeball_fill.cc)
};

}  // namespace face_reenact::reenact::internal
