// libFuzzer target: the .pts reader must turn any text into either 68 finite points or a
// face_reenact::Error, never a crash, hang or other exception.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "face_reenact/common/error.h"
#include "face_reenact/landmarks/evaluation.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const face_reenact::landmarks::Shape68 shape = face_reenact::landmarks::parse_pts(text, "fuzz");
    for (const auto& p : shape) {
      if (!std::isfinite(p.x()) || !std::isfinite(p.y())) std::abort();
    }
  } catch (const face_reenact::Error&) {
  }
  return 0;
}
