#!/usr/bin/env bash
# Builds the Debian packages of a build tree with CPack into a scratch folder and checks what a
# person installing them gets (README, "Packages"; issue #29):
#   - stripped binaries (no .debug_* sections, no symbol table);
#   - the doc folder named after each package, with the copyright file and the changelog;
#   - Depends / Recommends that make the program work on a fresh machine (a Vulkan driver,
#     dlib's landmark model; v4l2loopback recommended);
#   - the v4l2loopback configuration in /etc, listed as conffiles, with the options the docs
#     and the program's messages give (one device, /dev/video10);
#   - the program from the unpacked package finds its face model and data (`model info`);
#   - lintian, when installed: no error (E:) line.
# Usage: check_packages.sh BUILD_DIR SOURCE_DIR WORK_DIR WITH_OBS(ON|OFF)
# Exit 77 (CTest: skipped) when the face model has not been built or dpkg-deb is missing.
set -euo pipefail

build="$1" src="$2" work="$3" with_obs="$4"
fail=0
bad() { printf 'FAIL: %s\n' "$*"; fail=1; }
ok() { printf 'ok: %s\n' "$*"; }

command -v dpkg-deb >/dev/null || { echo "skipped: dpkg-deb is not installed"; exit 77; }
model="$(sed -n 's/^FR_MODEL_FILE:FILEPATH=//p' "$build/CMakeCache.txt")"
if [ ! -f "$model" ]; then
  echo "skipped: the face model $model has not been built (face-reenact model build), so the package would lack it"
  exit 77
fi

rm -rf "$work" && mkdir -p "$work"
start=$(date +%s)
cpack --config "$build/CPackConfig.cmake" -B "$work" >"$work/cpack.log" 2>&1 || { cat "$work/cpack.log"; exit 1; }
echo "cpack: $(( $(date +%s) - start )) s"
rm -rf "$work/_CPack_Packages"

packages=(face-reenact)
[ "$with_obs" = ON ] && packages+=(obs-face-reenact)
shopt -s nullglob
for p in "${packages[@]}"; do
  debs=("$work/${p}"_*.deb)
  [ ${#debs[@]} -eq 1 ] || { bad "expected one ${p}_*.deb in $work, found ${#debs[@]}"; continue; }
  deb="${debs[0]}"
  root="$work/root-$p" ctl="$work/control-$p"
  dpkg-deb -x "$deb" "$root"
  dpkg-deb -e "$deb" "$ctl"
  field() { dpkg-deb -f "$deb" "$1"; }
  echo "$(basename "$deb"): $(du -k "$deb" | cut -f1) KiB, Installed-Size $(field Installed-Size) KiB"

  # Doc folder under the package's own name, with copyright and changelog.
  [ -f "$root/usr/share/doc/$p/copyright" ] && ok "$p: /usr/share/doc/$p/copyright" ||
    bad "$p: no /usr/share/doc/$p/copyright"
  [ -f "$root/usr/share/doc/$p/changelog.gz" ] && gzip -t "$root/usr/share/doc/$p/changelog.gz" &&
    ok "$p: /usr/share/doc/$p/changelog.gz" || bad "$p: no valid /usr/share/doc/$p/changelog.gz"
  others=$(find "$root/usr/share/doc" -mindepth 1 -maxdepth 1 ! -name "$p" -printf '%f ')
  [ -z "$others" ] && ok "$p: no other doc folder" || bad "$p: doc folders other than $p: $others"

  # Every ELF file stripped: no debug sections and no static symbol table.
  while IFS= read -r -d '' f; do
    head -c4 "$f" | grep -q $'^\x7fELF' || continue
    sections=$(readelf -SW "$f" | grep -oE '\.(debug_[a-z_]+|symtab)' | sort -u | tr '\n' ' ' || true)
    rel="/${f#"$root"/}"
    [ -z "$sections" ] && ok "$p: $rel stripped ($(du -k "$f" | cut -f1) KiB)" || bad "$p: $rel not stripped: $sections"
  done < <(find "$root" -type f -print0)
done

# face-reenact: what makes it work on a fresh machine, and the virtual camera's configuration.
deb=("$work"/face-reenact_*.deb)
if [ ${#deb[@]} -eq 1 ]; then
  deb="${deb[0]}" root="$work/root-face-reenact" ctl="$work/control-face-reenact"
  depends="$(dpkg-deb -f "$deb" Depends)" recommends="$(dpkg-deb -f "$deb" Recommends)"
  echo "face-reenact Depends: $depends"
  echo "face-reenact Recommends: $recommends"
  [[ "$depends" == *"mesa-vulkan-drivers | vulkan-icd"* ]] && ok "Depends: a Vulkan driver" || bad "Depends lacks 'mesa-vulkan-drivers | vulkan-icd'"
  [[ "$depends" == *"libdlib-data"* ]] && ok "Depends: libdlib-data" || bad "Depends lacks libdlib-data"
  [[ "$depends" == *"libvulkan1"* ]] && ok "Depends: libvulkan1 (shlibdeps)" || bad "Depends lacks libvulkan1: dpkg-shlibdeps did not run?"
  [[ "$recommends" == *"v4l2loopback-dkms"* ]] && ok "Recommends: v4l2loopback-dkms" || bad "Recommends lacks v4l2loopback-dkms"
  for f in /etc/modprobe.d/face-reenact.conf /etc/modules-load.d/face-reenact.conf; do
    [ -f "$root$f" ] && ok "ships $f" || bad "does not ship $f"
    grep -qx "$f" "$ctl/conffiles" 2>/dev/null && ok "conffile $f" || bad "$f is not in conffiles"
  done
  grep -qx 'v4l2loopback' "$root/etc/modules-load.d/face-reenact.conf" && ok "modules-load.d loads v4l2loopback" ||
    bad "modules-load.d/face-reenact.conf does not name v4l2loopback"
  options=$(sed -n 's/^options v4l2loopback //p' "$root/etc/modprobe.d/face-reenact.conf")
  [ "$options" = 'devices=1 video_nr=10 card_label="Face Reenact" exclusive_caps=1' ] &&
    ok "modprobe.d options: $options" || bad "modprobe.d options are '$options'"
  # The docs and the program's message for a missing device give the same line.
  grep -qF "modprobe v4l2loopback $options" "$src/docs/virtual-webcam.md" && ok "docs/virtual-webcam.md gives the same options" ||
    bad "docs/virtual-webcam.md has no 'modprobe v4l2loopback $options'"
  msg=$("$root/usr/bin/face-reenact" webcam --device "$work/no-such-video-node" --seconds 1 2>&1 || true)
  [[ "$msg" == *"modprobe v4l2loopback $options"* ]] && ok "the missing-device message gives the same options" ||
    bad "the missing-device message does not give the package's options: $msg"
  [ -f "$root/usr/share/face-reenact/face-model.frm" ] && ok "ships the face model" || bad "no /usr/share/face-reenact/face-model.frm"
  [ -f "$root/usr/share/face-reenact/face-teeth.png" ] && ok "ships the teeth texture" || bad "no /usr/share/face-reenact/face-teeth.png"
  [ -f "$root/usr/share/man/man1/face-reenact.1.gz" ] && ok "ships the manual page" || bad "no manual page"
  # The unpacked program finds the model and data beside itself, as the installed one will.
  info=$(env -u FACE_REENACT_MODEL -u FR_MODEL "$root/usr/bin/face-reenact" model info 2>&1) &&
    [[ "$info" == *"$root/usr/bin/../share/face-reenact/face-model.frm"* || "$info" == *"$root/usr/share/face-reenact/face-model.frm"* ]] &&
    ok "unpacked face-reenact model info reads the packaged model" || bad "unpacked face-reenact model info: $info"
fi
if [ "$with_obs" = ON ]; then
  deb=("$work"/obs-face-reenact_*.deb)
  if [ ${#deb[@]} -eq 1 ]; then
    depends="$(dpkg-deb -f "${deb[0]}" Depends)"
    echo "obs-face-reenact Depends: $depends"
    version="$(dpkg-deb -f "${deb[0]}" Version)"
    [[ "$depends" == *"obs-studio (>= 29)"* && "$depends" == *"face-reenact (= $version)"* ]] &&
      ok "obs-face-reenact depends on obs-studio and its own face-reenact" || bad "obs-face-reenact Depends: $depends"
  fi
fi

# lintian: errors fail; the warnings kept are explained in README ("Packages").
if command -v lintian >/dev/null; then
  start=$(date +%s)
  lintian --tag-display-limit 0 "$work"/*.deb >"$work/lintian.log" 2>&1 || true
  echo "lintian ($(( $(date +%s) - start )) s):"
  cat "$work/lintian.log"
  grep -q '^E: ' "$work/lintian.log" && bad "lintian reports errors" || ok "lintian: no errors"
else
  echo "lintian is not installed (./setup.sh package installs it): not run"
fi

[ $fail -eq 0 ] && echo "all package checks passed" || echo "some package checks failed"
exit $fail
