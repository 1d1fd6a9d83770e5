// libFuzzer target: the face model loader must turn any byte string into either a valid
// FaceModel or a face_reenact::Error — never a crash, a hang, a sanitizer report or an
// allocation driven by a forged length.
#include <cstddef>
#include <cstdint>
#include <span>

#include "face_reenact/common/error.h"
#include "face_reenact/model/model_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    face_reenact::FaceModel m = face_reenact::parse_face_model(std::span<const uint8_t>(data, size), "fuzz input");
    // Whatever parses must be consistent enough to evaluate and to serialise again.
    (void)m.shape(Eigen::VectorXf::Zero(m.num_identity()), Eigen::VectorXf::Zero(m.num_expression()));
    (void)face_reenact::serialize_face_model(m);
  } catch (const face_reenact::Error&) {
  }
  return 0;
}
