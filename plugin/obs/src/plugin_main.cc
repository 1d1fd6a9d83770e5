// The OBS module "face-reenact": registers the "Face Reenact" source (docs/obs-source.md).
#include <obs-module.h>

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
