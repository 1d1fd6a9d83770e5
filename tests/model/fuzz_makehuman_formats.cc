// libFuzzer target for every text format the model builder reads from the wheel: morph targets,
// the OBJ base mesh, the mirror table, macro.json, the landmark file, and gzip members. The first
// byte picks the parser; bad input must end in face_reenact::Error, never a crash or a hang.
#include <cstddef>
#include <cstdint>
#include <string>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model_builder.h"
#include "face_reenact/model/macro_modifiers.h"
#include "face_reenact/model/makehuman_formats.h"
#include "face_reenact/model/wheel_archive.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace face_reenact;
  if (size < 1) return 0;
  const std::string text(reinterpret_cast<const char*>(data + 1), size - 1);
  try {
    switch (data[0] % 6) {
      case 0: parse_morph_target(text, 64, "fuzz"); break;
      case 1: parse_obj(text, "fuzz"); break;
      case 2: parse_mirror_table(text, 16, "fuzz"); break;
      case 3: {
        MacroRules r = MacroRules::parse(text, "fuzz");
        for (const auto& [name, parts] : r.variables()) r.label_weights(name, 0.37);
        macro_target_weights(r, MacroParameters());
        break;
      }
      case 4: parse_landmark_file(text, "fuzz"); break;
      case 5: gunzip({data + 1, size - 1}, "fuzz", 1 << 20); break;
    }
  } catch (const Error&) {
  }
  return 0;
}
