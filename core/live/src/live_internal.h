#pragma once
// Internal to fr_live.
#include <memory>

#include "face_reenact/live/frame_grabber.h"

namespace face_reenact::live {

// An OpenNI2 RGB-D device (options.input.device_path: URI, "" = the first device, or a .oni
// file). Throws face_reenact::Error when none opens, or when this build has no OpenNI2.
std::unique_ptr<InputDevice> open_openni_device(const GrabberOptions& options);

}  // namespace face_reenact::live
