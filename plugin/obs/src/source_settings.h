#pragma once
// The "Face Reenact" source's settings: the keys (docs/obs-source.md documents each one), their
// defaults, and the translation of a settings object into the live session's options. Kept
// apart from the callbacks so the mapping is tested without a running OBS.
#include <obs-module.h>

#include <string>
#include <vector>

#include "face_reenact/live/live_session.h"

namespace face_reenact::obs_plugin {

inline constexpr const char* kSourceId = "face_reenact_source";
inline constexpr const char* kLogPrefix = "[face-reenact]";

// Setting keys (stable: they are stored in users' scene collections).
inline constexpr const char* kTargetKind = "target_kind";      // "camera" | "recording" | "openni"
inline constexpr const char* kTargetCamera = "target_camera";  // /dev/videoN
inline constexpr const char* kTargetPath = "target_path";      // recording folder or video file (or .oni)
inline constexpr const char* kSourceKind = "source_kind";      // "none" | "udp" | "camera" | "recording"
inline constexpr const char* kUdpPort = "udp_port";            // 1..65535
inline constexpr const char* kKeyFile = "key_file";            // the stream key file
inline constexpr const char* kSourceCamera = "source_camera";  // /dev/videoN of the source actor
inline constexpr const char* kSourcePath = "source_path";      // recording/video of the source actor
inline constexpr const char* kModelPath = "model_path";        // face model (.frm)
inline constexpr const char* kMode = "mode";                   // "reenact" | "passthrough" | "overlay" | "mirror" | "raw"
// The virtual mirror (mode "mirror"): an image painted on the face, where, how opaque, and a light.
inline constexpr const char* kMirrorTexture = "mirror_texture";  // image file (PNG with alpha), "" for none
inline constexpr const char* kMirrorAt = "mirror_at";            // "face" | "forehead" | "nose" | "left-cheek" | ...
inline constexpr const char* kMirrorOpacity = "mirror_opacity";  // 0..1
inline constexpr const char* kMirrorLight = "mirror_light";      // "" (the camera's) | a preset name
inline constexpr const char* kMirrorLightFile = "mirror_light_file";  // a .json with "gamma" (overrides the preset)
inline constexpr const char* kDetail = "detail";  // "transient" | "copy" | "off": the source actor's folds (Sec. 7.3)
inline constexpr const char* kMouth = "mouth";    // "auto" | "target" | "model": an opened mouth's interior
inline constexpr const char* kCameraResolution = "camera_resolution";  // "640x480", ...
inline constexpr const char* kCalibrate = "calibrate";         // button
inline constexpr const char* kStatus = "status";               // read-only status line

inline constexpr int kDefaultUdpPort = 9000;

// Fills the defaults (model path: where the program finds it, when it does).
void set_defaults(obs_data_t* settings);

// The session's options for these settings. On settings that cannot work (no recording chosen,
// no key file for a stream) returns false with *why in plain words (shown as the status).
bool options_from_settings(obs_data_t* settings, live::LiveSession::Options* options, std::string* why);

// V4L2 capture devices present now (/dev/video*, sorted), for the camera lists.
std::vector<std::string> list_video_devices();

}  // namespace face_reenact::obs_plugin
