#!/bin/sh
# Runs inside the clean Debian root after `apt-get install ./face-reenact_*.deb
# ./obs-face-reenact_*.deb` (tests/packaging/clean_root_install.sh): what a person who installed
# the packages on a fresh machine runs first.
set -eu
echo "--- face-reenact --help"
face-reenact --help
echo "--- face-reenact model info"
face-reenact model info
echo "--- face-reenact devices (the Vulkan driver the package depends on)"
face-reenact devices
echo "--- the virtual camera's configuration (conffiles)"
cat /etc/modprobe.d/face-reenact.conf /etc/modules-load.d/face-reenact.conf
dpkg-query -W -f='${Conffiles}\n' face-reenact
echo "--- OBS loads the module from its default folders"
# libobs does not start without an X display (obs_startup: "Unable to open X display").
Xvfb :77 -nolisten tcp -screen 0 640x480x24 >/tmp/xvfb.log 2>&1 &
xvfb=$!
i=0
while [ ! -S /tmp/.X11-unix/X77 ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
status=0
DISPLAY=:77 python3 /tmp/obs_load_module.py || status=$?
kill $xvfb
[ $status -eq 0 ] || { echo "OBS could not load the module"; exit 1; }
echo "--- installed"
dpkg-query -W -f='${Package} ${Version} ${Installed-Size} KiB\n' face-reenact obs-face-reenact
echo "all checks in the clean root passed"
