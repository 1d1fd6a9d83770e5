#!/usr/bin/env bash
# Installs the Debian packages into a clean Debian bookworm root and runs them there, as a person
# with a fresh machine would (README, "Packages"; issue #29):
#   mmdebstrap makes a minimal root (variant apt); inside it `apt-get install
#   --no-install-recommends ./face-reenact_*.deb ./obs-face-reenact_*.deb` pulls what their
#   Depends name from the Debian mirror (obs-studio included): without recommends, so the Depends
#   alone must make the program work (xvfb comes along: libobs needs an X display to start). Then
#   in_root_checks.sh runs `face-reenact --help`, `model info`, `devices` and loads the OBS module
#   through libobs (obs_load_module.py).
# Usage: clean_root_install.sh PACKAGE_DIR WORK_DIR
#   PACKAGE_DIR  the .deb files (./setup.sh package puts them in out/packages)
#   WORK_DIR     keeps downloaded .deb files between runs (apt-cache/) and the log
# Needs root (or mmdebstrap's unshare mode) and the Debian mirror: FR_DEBIAN_MIRROR (default
# http://deb.debian.org/debian; the security updates come from FR_DEBIAN_SECURITY_MIRROR, default
# http://deb.debian.org/debian-security). Exit 77 (CTest: skipped) when mmdebstrap is missing,
# when not root, when the mirror cannot be reached or when PACKAGE_DIR holds no packages.
set -euo pipefail
skip() { echo "skipped: $*"; exit 77; }

[ $# -eq 2 ] || { echo "usage: $0 PACKAGE_DIR WORK_DIR" >&2; exit 2; }
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
pkgdir="$(cd "$1" && pwd)"
work="$2"
command -v mmdebstrap >/dev/null || skip "mmdebstrap is not installed (./setup.sh package-test installs it)"
# mmdebstrap's root mode; its unshare mode would need subordinate ids set up for the user.
[ "$(id -u)" -eq 0 ] || skip "needs root to build the root with mmdebstrap"
shopt -s nullglob
debs=("$pkgdir"/face-reenact_*.deb "$pkgdir"/obs-face-reenact_*.deb)
[ ${#debs[@]} -eq 2 ] || skip "no face-reenact_*.deb and obs-face-reenact_*.deb in $pkgdir"
mirror="${FR_DEBIAN_MIRROR:-http://deb.debian.org/debian}"
security="${FR_DEBIAN_SECURITY_MIRROR:-http://deb.debian.org/debian-security}"
python3 -c 'import sys, urllib.request; urllib.request.urlopen(sys.argv[1], timeout=15).close()' \
    "$mirror/dists/bookworm/InRelease" 2>/dev/null || skip "the Debian mirror $mirror cannot be reached"
mkdir -p "$work/apt-cache"
work="$(cd "$work" && pwd)"

start=$(date +%s)
# The packages downloaded last time are put into the root's apt cache first and the new ones
# taken out at the end (mmdebstrap's documented caching hooks), so a second run downloads only
# what changed. The root itself is thrown away (target /dev/null).
mmdebstrap --variant=apt --skip=essential/unlink \
  --setup-hook='mkdir -p "$1/var/cache/apt/archives"' \
  --setup-hook="sync-in '$work/apt-cache' /var/cache/apt/archives" \
  --customize-hook="copy-in ${debs[*]} '$here/in_root_checks.sh' '$here/obs_load_module.py' /tmp" \
  --customize-hook='chroot "$1" sh -c "DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends /tmp/*.deb xvfb"' \
  --customize-hook="sync-out /var/cache/apt/archives '$work/apt-cache'" \
  --customize-hook='chroot "$1" sh /tmp/in_root_checks.sh' \
  bookworm /dev/null \
  "deb $mirror bookworm main" "deb $mirror bookworm-updates main" "deb $security bookworm-security main" \
  2>&1 | tee "$work/clean_root_install.log"
echo "clean-root install and checks: $(( $(date +%s) - start )) s (downloaded .deb files kept in $work/apt-cache)"
