#pragma once
// Expression transfer (paper Sec. 7.2, Eq. 15) in blendshape space.
//
// The paper transfers the source's expression *deformation* delta onto the target's neutral
// mesh by deformation transfer. Our expression basis E_exp is one set of 52 ARKit blendshapes
// shared by every identity (Eq. 1: M = a_id + E_id alpha + E_exp delta), so a blendshape weight
// vector means the same motion on any face, and deformation transfer of the delta reduces to
// adding the weight delta:
//   delta_T' = delta_T,neutral + (delta_S - delta_S,neutral),   clamped to [0, 1] per weight.
// The neutral subtraction removes each actor's resting face (a source whose mouth rests a little
// open does not open the target's), as in the paper.
#include <Eigen/Core>

#include "face_reenact/reenact/reenactment_pipeline.h"

namespace face_reenact::reenact {

// Eq. 15 plus the stream's cross-fade: with w = source.blend_weight,
//   out = clamp01(w * (target_neutral + source.relative()) + (1 - w) * target_own).
// `target_neutral` and `target_own` may be shorter than 52 (missing weights are 0); the result
// has `size` entries (>= 52: the rest are copied from target_own, then 0). Throws
// face_reenact::Error on an invalid source.
Eigen::VectorXf TransferExpression(const Eigen::VectorXf& target_neutral, const Eigen::VectorXf& target_own,
                                   const SourceExpression& source, int size = kNumExpressionWeights);

// The target's parameters with the transferred expression: identity, albedo, pose and lighting
// are the target's own (`target_tracked`); only delta changes.
gpu::FaceParameters TransferParameters(const gpu::FaceParameters& target_tracked,
                                       const gpu::FaceParameters& target_neutral, const SourceExpression& source);

// ARKit indices used by the mouth stage.
inline constexpr int kJawOpenIndex = 17;   // "jawOpen" (checked by a test)
inline constexpr int kTongueOutIndex = 51;  // "tongueOut"

// Weight `index` of delta, 0 when delta is shorter.
inline float expression_weight(const Eigen::VectorXf& delta, int index) {
  return index < delta.size() ? delta[index] : 0.0f;
}

}  // namespace face_reenact::reenact
