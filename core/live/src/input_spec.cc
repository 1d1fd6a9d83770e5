#include "face_reenact/live/input_spec.h"

#include <cctype>
#include <filesystem>

#include "face_reenact/capture/recording.h"
#include "face_reenact/common/error.h"

namespace face_reenact::live {
namespace {

bool all_digits(const std::string& s) {
  if (s.empty() || s.size() > 3) return false;
  for (char c : s)
    if (!std::isdigit(static_cast<unsigned char>(c))) return false;
  return true;
}

std::string trim(const std::string& s) {
  size_t b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  size_t e = s.find_last_not_of(" \t\r\n");
  return s.substr(b, e - b + 1);
}

// Camera, OpenNI or recording; nullopt-like kNone when the text is none of these.
InputSpec parse_capture(const std::string& text) {
  InputSpec spec;
  spec.text = text;
  if (text.rfind("/dev/video", 0) == 0 && all_digits(text.substr(10))) {
    spec.kind = InputKind::kCamera;
    spec.device_path = text;
  } else if (text.rfind("video", 0) == 0 && all_digits(text.substr(5))) {
    spec.kind = InputKind::kCamera;
    spec.device_path = "/dev/" + text;
  } else if (all_digits(text)) {
    spec.kind = InputKind::kCamera;
    spec.device_path = "/dev/video" + text;
  } else if (text == "openni") {
    spec.kind = InputKind::kOpenNi;
  } else if (text.rfind("openni:", 0) == 0) {
    spec.kind = InputKind::kOpenNi;
    spec.device_path = text.substr(7);
  } else if (has_oni_extension(text)) {
    // An .oni file given as a plain path is an OpenNI recording (OpenNI2's file driver plays it).
    spec.kind = InputKind::kOpenNi;
    spec.device_path = text;
  } else {
    spec.kind = InputKind::kRecording;
    spec.path = text;
  }
  return spec;
}

}  // namespace

const char* input_kind_name(InputKind kind) {
  switch (kind) {
    case InputKind::kNone: return "none";
    case InputKind::kCamera: return "camera";
    case InputKind::kOpenNi: return "openni";
    case InputKind::kRecording: return "recording";
    case InputKind::kUdp: return "udp";
  }
  return "?";
}

std::string InputSpec::describe() const {
  switch (kind) {
    case InputKind::kNone: return "none";
    case InputKind::kCamera: return "camera " + device_path;
    case InputKind::kOpenNi: return device_path.empty() ? "OpenNI device (first found)" : "OpenNI '" + device_path + "'";
    case InputKind::kRecording: return "recording '" + path + "'";
    case InputKind::kUdp: return "udp " + listen;
  }
  return text;
}

bool has_oni_extension(const std::string& text) {
  if (text.size() <= 4) return false;
  std::string ext = text.substr(text.size() - 4);
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext == ".oni";
}

InputSpec parse_target_spec(const std::string& raw, const std::string& what) {
  std::string text = trim(raw);
  if (text.empty() || text == "none")
    throw Error(what + ": no target input given (a camera such as /dev/video0, 'openni', or a recording/video path)");
  if (text.rfind("udp://", 0) == 0)
    throw Error(what + " '" + text + "': a UDP expression stream cannot be the target (it carries no pictures)");
  return parse_capture(text);
}

InputSpec parse_source_spec(const std::string& raw, const std::string& what) {
  std::string text = trim(raw);
  if (text.empty() || text == "none") {
    InputSpec spec;
    spec.text = text;
    return spec;
  }
  if (text.rfind("udp://", 0) == 0) {
    InputSpec spec;
    spec.kind = InputKind::kUdp;
    spec.text = text;
    spec.listen = text.substr(6);
    if (spec.listen.empty()) throw Error(what + " '" + text + "': udp:// needs a port, e.g. udp://9000");
    return spec;
  }
  return parse_capture(text);
}

void CheckRecordingOpens(const InputSpec& spec) {
  if (spec.kind != InputKind::kRecording) return;
  std::error_code ec;
  if (!std::filesystem::exists(spec.path, ec)) throw Error("recording '" + spec.path + "': no such file or folder");
  (void)capture::open_frame_source(spec.path);  // validates the recording / video
}

}  // namespace face_reenact::live
