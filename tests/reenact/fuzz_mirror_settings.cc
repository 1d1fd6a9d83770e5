// Fuzz entry point with libFuzzer's signature, run over its seeds and their mutations by
// tests/support/fuzz_regression_test.cc: the virtual mirror's settings from text
// (docs/reenactment.md, "Virtual mirror"), a texture placement ("uv:U0,V0,U1,V1" or a region name) and a light
// file's JSON ("gamma": 27 numbers). Each must become a valid placement / light or a
// face_reenact::Error, never a crash, a hang or another exception. The input's first line is the
// placement, the rest the light's text.
#include <cstdint>
#include <cstdlib>
#include <string>

#include "face_reenact/common/error.h"
#include "face_reenact/reenact/virtual_mirror.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace face_reenact;
  const std::string text(reinterpret_cast<const char*>(data), size);
  const size_t line_end = text.find('\n');
  const std::string at = text.substr(0, line_end);
  const std::string light = line_end == std::string::npos ? std::string() : text.substr(line_end + 1);
  std::string why;
  try {
    const reenact::TexturePlacement p = reenact::ParseTexturePlacement(at);
    if (!p.region && !p.uv.IsValid(&why)) std::abort();  // a placement it accepted must be usable
  } catch (const Error&) {
  }
  try {
    const reenact::MirrorLight l = reenact::ParseLightJson(light, "fuzz");
    if (!l.IsValid(&why)) std::abort();
  } catch (const Error&) {
  }
  return 0;
}
