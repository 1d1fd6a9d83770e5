#pragma once
// What the user names as an input of a live session, parsed once into a plain struct. The same
// text works in the OBS source's properties, the webcam command's --target/--source and tests:
//
//   /dev/video2, video2, 2        a V4L2 camera (OpenCV's V4L2 backend)
//   openni, openni:URI            an OpenNI2 RGB-D device (the first one, or by URI; a .oni
//                                 recording plays through OpenNI's file driver)
//   FILE.oni                      the same as openni:FILE.oni
//   udp://PORT, udp://ADDR:PORT   the expression stream (expression sources only; needs a key)
//   none, (empty)                 no input (expression sources only)
//   anything else                 a recording folder (docs/recording-format.md) or a video file
#include <string>

namespace face_reenact::live {

enum class InputKind {
  kNone,       // no expression source: the target keeps its own expression
  kCamera,     // V4L2 camera
  kOpenNi,     // OpenNI2 device or .oni file
  kRecording,  // recording folder or video file (played in a loop at its own frame rate)
  kUdp,        // expression stream over UDP (stream::ExpressionReceiver)
};
const char* input_kind_name(InputKind kind);

struct InputSpec {
  InputKind kind = InputKind::kNone;
  std::string text;         // as the user wrote it (for messages)
  std::string device_path;  // kCamera: /dev/videoN; kOpenNi: the URI ("" = any device)
  std::string path;         // kRecording: folder or video file
  std::string listen;       // kUdp: "PORT" or "ADDR:PORT" (stream::parse_listen_spec syntax)

  // "camera /dev/video2", "recording 'talk.mp4'", "udp port 9000".
  std::string describe() const;
};

// Parses a target (camera, OpenNI or recording). Throws face_reenact::Error for empty text, udp
// or none (`what` names the option in the message).
InputSpec parse_target_spec(const std::string& text, const std::string& what);
// True when `path` ends in .oni (any case): an OpenNI recording, not a device.
bool has_oni_extension(const std::string& path);
// Parses an expression source: none/empty, udp://..., or a camera/OpenNI/recording actor.
InputSpec parse_source_spec(const std::string& text, const std::string& what);

// For a recording: that it exists and opens as a recording or a video (throws face_reenact::Error
// saying which, e.g. "recording 'x.mp4': no such file or folder"); nothing for other kinds. The
// front-ends call it before loading the face model and the landmark models (seconds on a cold
// disk), so a typo is reported at once.
void CheckRecordingOpens(const InputSpec& spec);

}  // namespace face_reenact::live
