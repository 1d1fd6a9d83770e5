// The obs_source_info of "Face Reenact": thin extern "C" callbacks into FaceReenactSource, the
// properties (every key documented in docs/obs-source.md) and a proc handler for scripts/tests.
#include <obs-module.h>

#include <exception>
#include <string>

#include "face_reenact_source.h"
#include "source_settings.h"

namespace face_reenact::obs_plugin {
namespace {

FaceReenactSource* self(void* data) { return static_cast<FaceReenactSource*>(data); }

const char* text(const char* key) { return obs_module_text(key); }

// Shows the fields that belong to the chosen kinds.
bool on_kind_modified(obs_properties_t* props, obs_property_t*, obs_data_t* settings) {
  std::string target = obs_data_get_string(settings, kTargetKind);
  std::string source = obs_data_get_string(settings, kSourceKind);
  obs_property_set_visible(obs_properties_get(props, kTargetCamera), target == "camera");
  obs_property_set_visible(obs_properties_get(props, kTargetPath), target == "recording" || target == "openni");
  obs_property_set_visible(obs_properties_get(props, kUdpPort), source == "udp");
  obs_property_set_visible(obs_properties_get(props, kKeyFile), source == "udp");
  obs_property_set_visible(obs_properties_get(props, kSourceCamera), source == "camera");
  obs_property_set_visible(obs_properties_get(props, kSourcePath), source == "recording");
  // Only a source actor filmed on this machine has folds and wrinkles to carry over.
  obs_property_set_visible(obs_properties_get(props, kDetail), source == "camera" || source == "recording");
  const std::string mode = obs_data_get_string(settings, kMode);
  obs_property_set_visible(obs_properties_get(props, kMouth), mode == "reenact");
  const bool mirror = mode == "mirror";
  for (const char* key : {kMirrorTexture, kMirrorAt, kMirrorOpacity, kMirrorLight, kMirrorLightFile})
    obs_property_set_visible(obs_properties_get(props, key), mirror);
  return true;
}

void add_camera_list(obs_properties_t* props, const char* key, const char* label) {
  obs_property_t* p = obs_properties_add_list(props, key, text(label), OBS_COMBO_TYPE_EDITABLE, OBS_COMBO_FORMAT_STRING);
  for (const std::string& device : list_video_devices()) obs_property_list_add_string(p, device.c_str(), device.c_str());
}

constexpr const char* kRecordingFilter =
    "Recordings and videos (recording.json *.mp4 *.mkv *.avi *.mov *.webm *.wmv *.oni);;All files (*.*)";

obs_properties_t* make_properties(FaceReenactSource* source) {
  obs_properties_t* props = obs_properties_create();

  std::string status = source ? source->status_line() : std::string(text("Status.NotRunning"));
  obs_property_t* status_p = obs_properties_add_text(props, kStatus, status.c_str(), OBS_TEXT_INFO);
  bool has_session = false;
  if (source) {
    live::LiveStatus s = source->live_status(&has_session);
    bool problem = !has_session || !s.target_open || s.source == live::SourceState::kError ||
                   s.source == live::SourceState::kLost || (s.mode != live::OutputMode::kRaw && !s.pipeline_ready);
    obs_property_text_set_info_type(status_p, problem ? OBS_TEXT_INFO_WARNING : OBS_TEXT_INFO_NORMAL);
  }

  obs_property_t* p = obs_properties_add_list(props, kTargetKind, text("TargetKind"), OBS_COMBO_TYPE_LIST, OBS_COMBO_FORMAT_STRING);
  obs_property_list_add_string(p, text("TargetKind.Camera"), "camera");
  obs_property_list_add_string(p, text("TargetKind.Recording"), "recording");
  obs_property_list_add_string(p, text("TargetKind.OpenNI"), "openni");
  obs_property_set_modified_callback(p, on_kind_modified);
  add_camera_list(props, kTargetCamera, "TargetCamera");
  obs_properties_add_path(props, kTargetPath, text("TargetPath"), OBS_PATH_FILE, kRecordingFilter, nullptr);
  p = obs_properties_add_list(props, kCameraResolution, text("CameraResolution"), OBS_COMBO_TYPE_EDITABLE, OBS_COMBO_FORMAT_STRING);
  for (const char* r : {"320x240", "640x480", "1280x720"}) obs_property_list_add_string(p, r, r);

  p = obs_properties_add_list(props, kSourceKind, text("SourceKind"), OBS_COMBO_TYPE_LIST, OBS_COMBO_FORMAT_STRING);
  obs_property_list_add_string(p, text("SourceKind.None"), "none");
  obs_property_list_add_string(p, text("SourceKind.Udp"), "udp");
  obs_property_list_add_string(p, text("SourceKind.Camera"), "camera");
  obs_property_list_add_string(p, text("SourceKind.Recording"), "recording");
  obs_property_set_modified_callback(p, on_kind_modified);
  obs_properties_add_int(props, kUdpPort, text("UdpPort"), 1, 65535, 1);
  obs_properties_add_path(props, kKeyFile, text("KeyFile"), OBS_PATH_FILE, "Key files (*.key);;All files (*.*)", nullptr);
  add_camera_list(props, kSourceCamera, "SourceCamera");
  obs_properties_add_path(props, kSourcePath, text("SourcePath"), OBS_PATH_FILE, kRecordingFilter, nullptr);
  p = obs_properties_add_list(props, kDetail, text("Detail"), OBS_COMBO_TYPE_LIST, OBS_COMBO_FORMAT_STRING);
  for (const char* mode : {"transient", "copy", "off"})
    obs_property_list_add_string(p, text((std::string("Detail.") + mode).c_str()), mode);

  obs_properties_add_path(props, kModelPath, text("ModelPath"), OBS_PATH_FILE, "Face model (*.frm);;All files (*.*)", nullptr);
  p = obs_properties_add_list(props, kMode, text("Mode"), OBS_COMBO_TYPE_LIST, OBS_COMBO_FORMAT_STRING);
  obs_property_list_add_string(p, text("Mode.Reenact"), "reenact");
  obs_property_list_add_string(p, text("Mode.PassThrough"), "passthrough");
  obs_property_list_add_string(p, text("Mode.Overlay"), "overlay");
  obs_property_list_add_string(p, text("Mode.Mirror"), "mirror");
  obs_property_list_add_string(p, text("Mode.Raw"), "raw");
  obs_property_set_modified_callback(p, on_kind_modified);
  p = obs_properties_add_list(props, kMouth, text("Mouth"), OBS_COMBO_TYPE_LIST, OBS_COMBO_FORMAT_STRING);
  for (const char* mouth : {"auto", "target", "model"})
    obs_property_list_add_string(p, text((std::string("Mouth.") + mouth).c_str()), mouth);
  obs_properties_add_path(props, kMirrorTexture, text("MirrorTexture"), OBS_PATH_FILE,
                          "Images (*.png *.jpg *.jpeg *.bmp *.webp);;All files (*.*)", nullptr);
  p = obs_properties_add_list(props, kMirrorAt, text("MirrorAt"), OBS_COMBO_TYPE_LIST, OBS_COMBO_FORMAT_STRING);
  for (const char* region : {"face", "forehead", "nose", "left-cheek", "right-cheek", "chin"})
    obs_property_list_add_string(p, text((std::string("MirrorAt.") + region).c_str()), region);
  obs_properties_add_float_slider(props, kMirrorOpacity, text("MirrorOpacity"), 0.0, 1.0, 0.05);
  p = obs_properties_add_list(props, kMirrorLight, text("MirrorLight"), OBS_COMBO_TYPE_LIST, OBS_COMBO_FORMAT_STRING);
  obs_property_list_add_string(p, text("MirrorLight.Camera"), "");
  for (const char* preset : {"front", "left", "right", "top", "bottom", "warm", "cool"})
    obs_property_list_add_string(p, text((std::string("MirrorLight.") + preset).c_str()), preset);
  obs_properties_add_path(props, kMirrorLightFile, text("MirrorLightFile"), OBS_PATH_FILE, "Light (*.json);;All files (*.*)",
                          nullptr);
  obs_properties_add_button(props, kCalibrate, text("Calibrate"), [](obs_properties_t*, obs_property_t*, void* data) {
    if (data) self(data)->calibrate();
    return false;
  });
  return props;
}

// proc handler "get_status": what the status line says, for scripts and the tests.
void proc_get_status(void* data, calldata_t* cd) {
  FaceReenactSource* source = self(data);
  bool has_session = false;
  live::LiveStatus s = source->live_status(&has_session);
  calldata_set_string(cd, "status", source->status_line().c_str());
  calldata_set_bool(cd, "running", has_session && s.running);
  calldata_set_bool(cd, "target_open", s.target_open);
  calldata_set_int(cd, "frames_out", s.frames_out);
  calldata_set_string(cd, "tracking", live::tracking_state_name(s.tracking));
  calldata_set_string(cd, "source_state", live::source_state_name(s.source));
  calldata_set_float(cd, "packets_per_second", s.packets_per_second);
}

void proc_calibrate(void* data, calldata_t*) { self(data)->calibrate(); }

extern "C" {

const char* fr_get_name(void*) { return text("FaceReenact"); }

void* fr_create(obs_data_t* settings, obs_source_t* source) {
  try {
    auto* s = new FaceReenactSource(settings, source);
    proc_handler_t* ph = obs_source_get_proc_handler(source);
    proc_handler_add(ph,
                     "void get_status(out string status, out bool running, out bool target_open, out int frames_out, "
                     "out string tracking, out string source_state, out float packets_per_second)",
                     proc_get_status, s);
    proc_handler_add(ph, "void calibrate()", proc_calibrate, s);
    return s;
  } catch (const std::exception& e) {
    blog(LOG_ERROR, "%s cannot create the source: %s", kLogPrefix, e.what());
    return nullptr;
  }
}

void fr_destroy(void* data) { delete self(data); }

void fr_update(void* data, obs_data_t* settings) {
  try {
    self(data)->update(settings);
  } catch (const std::exception& e) {
    blog(LOG_ERROR, "%s update failed: %s", kLogPrefix, e.what());
  }
}

void fr_get_defaults(obs_data_t* settings) { set_defaults(settings); }

obs_properties_t* fr_get_properties(void* data) { return make_properties(self(data)); }

void fr_video_tick(void* data, float) { self(data)->video_tick(); }

}  // extern "C"

}  // namespace

void register_source() {
  obs_source_info info = {};
  info.id = kSourceId;
  info.type = OBS_SOURCE_TYPE_INPUT;
  info.output_flags = OBS_SOURCE_ASYNC_VIDEO | OBS_SOURCE_DO_NOT_DUPLICATE;
  info.icon_type = OBS_ICON_TYPE_CAMERA;
  info.get_name = fr_get_name;
  info.create = fr_create;
  info.destroy = fr_destroy;
  info.update = fr_update;
  info.get_defaults = fr_get_defaults;
  info.get_properties = fr_get_properties;
  info.video_tick = fr_video_tick;
  obs_register_source(&info);
}

}  // namespace face_reenact::obs_plugin
