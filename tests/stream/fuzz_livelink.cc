// libFuzzer target: the Live Link Face packet parser. Invariant: a packet that parses
// re-encodes to exactly the input bytes (the layout has no slack), and its frame conversion
// never produces non-finite values.
#include <cmath>
#include <cstdint>
#include <cstring>

#include "face_reenact/stream/livelink.h"

using namespace face_reenact::stream;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  LiveLinkPacket p;
  std::string why;
  if (!parse_livelink_packet(std::span<const uint8_t>(data, size), &p, &why)) {
    if (why.empty()) __builtin_trap();
    return 0;
  }
  const std::vector<uint8_t> again = encode_livelink_packet(p);
  if (again.size() != size || std::memcmp(again.data(), data, size) != 0) __builtin_trap();
  const ExpressionFrame f = livelink_to_frame(p, 1);
  for (float r : f.rotation)
    if (!std::isfinite(r)) __builtin_trap();
  (void)frame_values_valid(f, &why);
  return 0;
}
