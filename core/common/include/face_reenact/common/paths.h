#pragma once
// Where the program finds its data (the generated face model, the files under data/, the
// per-user cache for downloaded registry data) and how it reads a file's name.
#include <string>

namespace face_reenact {

// ${XDG_CACHE_HOME:-$HOME/.cache}/face-reenact (created on demand by callers).
std::string user_cache_dir();
// The folder of the running executable.
std::string executable_dir();
// Resolves the face model file: explicit path if non-empty, else $FACE_REENACT_MODEL, else
// face-model.frm next to the executable, else the installed share/face-reenact copy.
// Throws face_reenact::Error listing what was tried.
std::string resolve_model_path(const std::string& explicit_path);
// Resolves a file shipped under data/ (source tree or installed share/face-reenact/data).
std::string resolve_data_file(const std::string& relative);

// ASCII lower case ("MP4" -> "mp4"): file extensions, device types and option values.
std::string ascii_lower(std::string text);
// The extension of `path` with its dot, in ASCII lower case: "clip.MP4" -> ".mp4"; "" when none.
std::string lower_case_extension(const std::string& path);

}  // namespace face_reenact
