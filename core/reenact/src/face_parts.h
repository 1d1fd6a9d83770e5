#pragma once
// The model's parts as the renderer's part masks (internal to fr_reenact): which parts a pass
// draws, and which of a pixel's vertices belong to the mouth's own surfaces.
#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/model/face_model.h"

namespace face_reenact::reenact::internal {

constexpr gpu::PartMask part_bit(FacePart p) { return gpu::PartMask{1} << static_cast<int>(p); }
// Teeth and tongue: drawn by the re-rendering, shaded by the mouth pass (mouth_pass.h).
constexpr gpu::PartMask kMouthParts =
    part_bit(FacePart::UpperTeeth) | part_bit(FacePart::LowerTeeth) | part_bit(FacePart::Tongue);
constexpr gpu::PartMask kEyeParts = part_bit(FacePart::LeftEye) | part_bit(FacePart::RightEye);

}  // namespace face_reenact::reenact::internal
