#pragma once
// What a fitted spherical-harmonics light may be. The tracker fits 27 free coefficients (Eq. 6),
// and nothing in the energy keeps them physical: the face shows a few normal directions only, so
// the fit can trade its ambient for a strong directional part and drift. Held on the Breaking Bad
// still and tracked for four seconds, the light's ambient fell frame by frame until blue's was
// below 0 by frame 30 and all three by frame 90, while the directional parts grew fourfold - on
// one unchanging picture (issue #26). Such a light says the face's shadow side receives negative
// light, and whatever reads the light afterwards (the re-rendered face's shading, the albedo map)
// inherits the nonsense.
//
// The test of plausibility: the order-2 SH irradiance of any light that is nowhere negative (any
// mix of distant lights and ambient) is at least -0.158 times its own mean over the sphere, the
// ringing of a single distant light's truncated clamped cosine (1/4 + cos/2 + 5/32 (3 cos^2 - 1)
// has its minimum -0.0396 where its mean is 1/4); mixtures only raise it. So in every direction n
//   E_c(n) = sum_k gamma_ck y_k(n) >= -kNegativeLobe * gamma_c0 y_0,
// which also keeps each channel's mean (its ambient) at or above 0. The tracker projects each
// channel onto that set after every solve (the nearest coefficients that meet it in 128 directions
// over the sphere), a projected Gauss-Newton: a plausible fit is left exactly as it is.
#include <algorithm>
#include <array>

#include "face_reenact/gpu/image_formation.h"

namespace face_reenact::tracker {

using ShLight = std::array<float, gpu::kNumShParameters>;  // gamma[channel * 9 + k]

// The lowest irradiance of `channel` over the sphere (128 directions), relative to its mean
// (the DC term's share); -inf where the mean is not above 0 and somewhere is negative, 0 for a
// channel without light (every coefficient under 1e-6).
float LowestRelativeIrradiance(const ShLight& light, int channel);

struct LightProjection {
  bool changed = false;    // some channel was not plausible
  float moved = 0.f;       // Euclidean distance the coefficients moved
};

// The margin below -0.158 that counts as plausible (rounding, the sampled directions).
inline constexpr float kNegativeLobe = 0.2f;

// Moves each implausible channel of `light` to the nearest coefficients (Euclidean) whose
// irradiance is at least -kNegativeLobe x its mean in every sampled direction; plausible channels
// stay bit for bit. Non-finite coefficients are left alone (the solver's own checks report them).
LightProjection ProjectToPlausibleLight(ShLight* light);

// Over the frames of a run: how often the fitted light had to be projected, and how far (the
// `light` section of `track --report` and `reenact --report`). A run where most frames need it
// has a light the frames do not explain (a still, an exposure drift): a reader of its shading
// should know.
struct LightProjectionTally {
  int frames = 0;     // frames fitted on their own (the ones Add was given)
  int projected = 0;  // of them, those whose light was moved
  double moved_sum = 0, moved_max = 0;
  void Add(const LightProjection& p) {
    ++frames;
    if (!p.changed) return;
    ++projected;
    moved_sum += p.moved;
    moved_max = std::max(moved_max, static_cast<double>(p.moved));
  }
  double moved_mean() const { return projected > 0 ? moved_sum / projected : 0.0; }
};

}  // namespace face_reenact::tracker
