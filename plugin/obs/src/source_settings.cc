#include "source_settings.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>

#include "face_reenact/common/paths.h"

namespace face_reenact::obs_plugin {

void set_defaults(obs_data_t* settings) {
  obs_data_set_default_string(settings, kTargetKind, "camera");
  obs_data_set_default_string(settings, kTargetCamera, "/dev/video0");
  obs_data_set_default_string(settings, kTargetPath, "");
  obs_data_set_default_string(settings, kSourceKind, "none");  // a picture at once; the stream needs a key first
  obs_data_set_default_int(settings, kUdpPort, kDefaultUdpPort);
  obs_data_set_default_string(settings, kKeyFile, "");
  obs_data_set_default_string(settings, kSourceCamera, "/dev/video1");
  obs_data_set_default_string(settings, kSourcePath, "");
  std::string model;
  try {
    model = resolve_model_path("");
  } catch (const std::exception&) {
    // Not installed / not generated: the field stays empty and the session says so.
  }
  obs_data_set_default_string(settings, kModelPath, model.c_str());
  obs_data_set_default_string(settings, kMode, "reenact");
  obs_data_set_default_string(settings, kMirrorTexture, "");
  obs_data_set_default_string(settings, kMirrorAt, "face");
  obs_data_set_default_double(settings, kMirrorOpacity, 1.0);
  obs_data_set_default_string(settings, kMirrorLight, "");
  obs_data_set_default_string(settings, kMirrorLightFile, "");
  obs_data_set_default_string(settings, kDetail, "transient");
  obs_data_set_default_string(settings, kMouth, "auto");
  obs_data_set_default_string(settings, kCameraResolution, "640x480");
}

namespace {

// OBS's file dialogs pick files: a recording folder is chosen through its recording.json.
std::string recording_path(std::string path) {
  const std::string marker = "recording.json";
  if (path.size() >= marker.size() && path.compare(path.size() - marker.size(), marker.size(), marker) == 0) {
    path.resize(path.size() - marker.size());
    if (path.size() > 1 && path.back() == '/') path.pop_back();
    if (path.empty()) path = ".";
  }
  return path;
}

}  // namespace

bool options_from_settings(obs_data_t* settings, live::LiveSession::Options* options, std::string* why) {
  auto str = [&](const char* key) { return std::string(obs_data_get_string(settings, key)); };
  auto fail = [&](const std::string& message) {
    *why = message;
    return false;
  };
  live::LiveSession::Options o;
  std::string target_kind = str(kTargetKind);
  if (target_kind == "camera") {
    o.target = str(kTargetCamera);
    if (o.target.empty()) return fail("choose a camera for the target");
  } else if (target_kind == "recording") {
    o.target = recording_path(str(kTargetPath));
    if (o.target.empty()) return fail("choose a recording or video file for the target");
  } else if (target_kind == "openni") {
    o.target = str(kTargetPath).empty() ? std::string("openni") : "openni:" + str(kTargetPath);
  } else {
    return fail("unknown target kind '" + target_kind + "'");
  }
  std::string source_kind = str(kSourceKind);
  if (source_kind == "none") {
    o.source = "none";
  } else if (source_kind == "udp") {
    long long port = obs_data_get_int(settings, kUdpPort);
    if (port < 1 || port > 65535) return fail("the UDP port must be in 1..65535");
    o.source = "udp://" + std::to_string(port);
    o.key_file = str(kKeyFile);
    if (o.key_file.empty()) return fail("choose the stream's key file (face-reenact keygen)");
  } else if (source_kind == "camera") {
    o.source = str(kSourceCamera);
    if (o.source.empty()) return fail("choose a camera for the source actor");
  } else if (source_kind == "recording") {
    o.source = recording_path(str(kSourcePath));
    if (o.source.empty()) return fail("choose a recording or video file for the source actor");
  } else {
    return fail("unknown expression source '" + source_kind + "'");
  }
  o.model_path = str(kModelPath);
  if (!live::parse_output_mode(str(kMode), &o.mode)) return fail("unknown output mode '" + str(kMode) + "'");
  o.mirror_texture = str(kMirrorTexture);
  o.mirror_at = str(kMirrorAt);
  o.mirror_opacity = static_cast<float>(obs_data_get_double(settings, kMirrorOpacity));
  o.mirror_light = str(kMirrorLightFile).empty() ? str(kMirrorLight) : str(kMirrorLightFile);
  if (o.mode == live::OutputMode::kMirror && o.mirror_texture.empty() && o.mirror_light.empty())
    return fail("the mirror needs an image to paint on the face or a light");
  o.detail = str(kDetail);
  o.mouth = str(kMouth);
  int w = 0, h = 0;
  char tail = 0;
  if (std::sscanf(str(kCameraResolution).c_str(), "%dx%d%c", &w, &h, &tail) == 2 && w > 0 && h > 0) {
    o.camera_width = w;
    o.camera_height = h;
  }
  if (!o.IsValid(why)) return false;
  *options = std::move(o);
  return true;
}

std::vector<std::string> list_video_devices() {
  std::vector<std::string> devices;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator("/dev", ec)) {
    std::string name = entry.path().filename().string();
    if (name.rfind("video", 0) == 0 && name.size() > 5) devices.push_back(entry.path().string());
  }
  std::sort(devices.begin(), devices.end(), [](const std::string& a, const std::string& b) {
    return a.size() != b.size() ? a.size() < b.size() : a < b;
  });
  return devices;
}

}  // namespace face_reenact::obs_plugin
