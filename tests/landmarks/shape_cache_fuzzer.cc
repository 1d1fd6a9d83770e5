// libFuzzer target: the shape predictor's cache copy (shape_predictor_cache.h) is read from the
// user's cache folder, where anything may have been left. Any bytes must parse into tables the
// predictor can evaluate (every index in range, every value finite) or be refused with a reason;
// never a crash, a hang, a sanitizer report or an allocation driven by a forged count.
#include <cstdint>
#include <cstdlib>
#include <span>
#include <string>

#include "face_reenact/common/error.h"
#include "shape_predictor_cache.h"

using namespace face_reenact::landmarks::detail;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // With the checksum and without: a mutated file nearly always fails the checksum, and the checks
  // behind it must hold on their own.
  for (const bool verify : {true, false}) {
    ShapeModelStamp stamp;
    ShapePredictorTables tables;
    std::string why;
    if (!parse_shape_cache(std::span<const uint8_t>(data, size), &stamp, &tables, &why, verify)) {
      if (why.empty()) std::abort();
      continue;
    }
    // What parses is what the writer writes: written again, it reads back with its checksum.
    try {
      const std::vector<uint8_t> again = serialize_shape_cache(stamp, tables);
      ShapeModelStamp s;
      ShapePredictorTables t;
      if (!parse_shape_cache(again, &s, &t, &why) || !(s == stamp)) std::abort();
    } catch (const face_reenact::Error&) {
      std::abort();
    }
  }
  return 0;
}
