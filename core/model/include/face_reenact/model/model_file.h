#pragma once
// The face model's on-disk format (".frm"), specified in docs/face-model-format.md:
// magic "FRMODEL\0", format version, little-endian marker, a section table (tag, offset, size,
// CRC-32 per section) and a CRC-32 over header and table. The loader rejects wrong magic,
// wrong version, truncation and corruption with a face_reenact::Error naming the problem.
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "face_reenact/model/face_model.h"

namespace face_reenact {

inline constexpr uint32_t kFaceModelFormatVersion = 1;

std::vector<uint8_t> serialize_face_model(const FaceModel& model);
// `what` names the input in error messages (a path, "buffer").
FaceModel parse_face_model(std::span<const uint8_t> bytes, const std::string& what = "face model");

void save_face_model(const FaceModel& model, const std::string& path);
FaceModel load_face_model(const std::string& path);

}  // namespace face_reenact
