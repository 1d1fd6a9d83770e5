// The OBS module "face-reenact": registers the "Face Reenact" source and, once every module is
// loaded, its obs-websocket vendor (docs/obs-source.md).
#include <obs-module.h>

#include "websocket_vendor.h"

OBS_DECLARE_MODULE()
OBS_MODULE_USE_DEFAULT_LOCALE("face-reenact", "en-US")

namespace face_reenact::obs_plugin {
void register_source();
}

MODULE_EXPORT const char* obs_module_description(void) {
  return "Face Reenact: real-time facial reenactment (Thies et al. 2015) as a video source";
}

bool obs_module_load(void) {
  face_reenact::obs_plugin::register_source();
  blog(LOG_INFO, "[face-reenact] module loaded (version " FR_VERSION ")");
  return true;
}

// After every module's obs_module_load: obs-websocket has set its vendor API up by now.
void obs_module_post_load(void) { face_reenact::obs_plugin::register_websocket_vendor(); }
