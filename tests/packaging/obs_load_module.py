#!/usr/bin/env python3
"""Loads the face-reenact OBS module the way OBS finds it: libobs starts (no video, no window),
searches its default module folders (obs_find_modules: on Debian /usr/lib/<multiarch>/obs-plugins
and /usr/share/obs/obs-plugins/<module>), opens and initialises `face-reenact` from there, and
the module's source "face_reenact_source" must then be registered. Run inside the root where the
obs-face-reenact package is installed (tests/packaging/clean_root_install.sh). Exit 0 on success."""
import ctypes
import sys

obs = ctypes.CDLL("libobs.so.0")
obs.obs_startup.restype = ctypes.c_bool
obs.obs_startup.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_void_p]
obs.obs_open_module.restype = ctypes.c_int
obs.obs_open_module.argtypes = [ctypes.POINTER(ctypes.c_void_p), ctypes.c_char_p, ctypes.c_char_p]
obs.obs_init_module.restype = ctypes.c_bool
obs.obs_init_module.argtypes = [ctypes.c_void_p]
obs.obs_source_get_display_name.restype = ctypes.c_char_p
obs.obs_source_get_display_name.argtypes = [ctypes.c_char_p]
obs.obs_get_version_string.restype = ctypes.c_char_p


class ModuleInfo(ctypes.Structure):  # struct obs_module_info (obs.h)
    _fields_ = [("bin_path", ctypes.c_char_p), ("data_path", ctypes.c_char_p)]


if not obs.obs_startup(b"en-US", None, None):
    sys.exit("obs_startup failed")
print("libobs", obs.obs_get_version_string().decode())
found = []
CALLBACK = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.POINTER(ModuleInfo))
callback = CALLBACK(lambda _param, info: found.append((info.contents.bin_path, info.contents.data_path)))
obs.obs_find_modules(callback, None)
ours = [(b, d) for b, d in found if b.endswith(b"/face-reenact.so")]
print(f"obs_find_modules: {len(found)} modules, face-reenact: {[(b.decode(), d.decode()) for b, d in ours]}")
if len(ours) != 1:
    sys.exit("OBS does not find the face-reenact module in its default folders")
module = ctypes.c_void_p()
rc = obs.obs_open_module(ctypes.byref(module), ours[0][0], ours[0][1])
if rc != 0:
    sys.exit(f"obs_open_module({ours[0][0].decode()}) returned {rc}")
if not obs.obs_init_module(module):
    sys.exit("obs_init_module(face-reenact) failed")
name = obs.obs_source_get_display_name(b"face_reenact_source")
if not name:
    sys.exit("the module loaded but registered no source face_reenact_source")
print(f"loaded {ours[0][0].decode()}: source face_reenact_source is '{name.decode()}'")
# No obs_shutdown: the process ends here, and libobs' shutdown without a video context is not
# what this checks.
