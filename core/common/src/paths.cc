#include "face_reenact/common/paths.h"

#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <filesystem>
#include <vector>

#include "face_reenact/common/error.h"

#ifndef FR_SOURCE_DATA_DIR
#define FR_SOURCE_DATA_DIR ""
#endif
#ifndef FR_INSTALL_DATA_DIR
#define FR_INSTALL_DATA_DIR ""
#endif

namespace face_reenact {
namespace fs = std::filesystem;

std::string user_cache_dir() {
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) return std::string(x) + "/face-reenact";
  if (const char* h = std::getenv("HOME"); h && *h) return std::string(h) + "/.cache/face-reenact";
  return "/tmp/face-reenact-cache";
}

std::string executable_dir() {
  std::error_code ec;
  auto p = fs::read_symlink("/proc/self/exe", ec);
  if (ec) return ".";
  return p.parent_path().string();
}

std::string resolve_model_path(const std::string& explicit_path) {
  if (!explicit_path.empty()) {
    if (!fs::exists(explicit_path)) throw Error("face model '" + explicit_path + "' does not exist");
    return explicit_path;
  }
  std::vector<std::string> tried;
  if (const char* env = std::getenv("FACE_REENACT_MODEL"); env && *env) {
    if (fs::exists(env)) return env;
    tried.push_back(std::string(env) + " ($FACE_REENACT_MODEL)");
  }
  const std::string exe = executable_dir();
  for (const std::string& c : {exe + "/face-model.frm", exe + "/../share/face-reenact/face-model.frm",
                               std::string(FR_INSTALL_DATA_DIR) + "/face-model.frm"}) {
    if (fs::exists(c)) return fs::weakly_canonical(c).string();
    tried.push_back(c);
  }
  std::string msg = "no face model found; build one with 'face-reenact model build' or pass --model. Tried:";
  for (auto& t : tried) msg += "\n  " + t;
  throw Error(msg);
}

std::string resolve_data_file(const std::string& relative) {
  const std::string exe = executable_dir();
  for (const std::string& base : {std::string(FR_SOURCE_DATA_DIR), exe + "/../share/face-reenact/data",
                                  std::string(FR_INSTALL_DATA_DIR) + "/data"}) {
    if (base.empty()) continue;
    fs::path p = fs::path(base) / relative;
    if (fs::exists(p)) return p.string();
  }
  throw Error("data file '" + relative + "' not found (looked in the source tree and the install prefix)");
}

std::string ascii_lower(std::string text) {
  std::transform(text.begin(), text.end(), text.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return text;
}

std::string lower_case_extension(const std::string& path) { return ascii_lower(fs::path(path).extension().string()); }

}  // namespace face_reenact
