#!/bin/bash
# Boots Debian's own kernel in QEMU with the real v4l2loopback module loaded (exclusive_caps=1)
# and runs a guest script against /dev/video0. The host's root file system is shared read-only
# over 9p, so the guest runs our freshly built `face-reenact`, v4l2-ctl and ffmpeg unchanged
# (through chroot); EXCHANGE_DIR is shared read-write and appears as /tmp inside the chroot.
#
#   run_v4l2_vm_test.sh CACHE_DIR EXCHANGE_DIR GUEST_SCRIPT [FR_CLI]
#
# EXCHANGE_DIR is emptied first; FR_CLI (the face-reenact executable to test) is handed to the
# guest script in EXCHANGE_DIR/env.sh.
#
# CACHE_DIR keeps the downloaded packages, the built module and the initramfs, so only the
# first run downloads (apt-get download) and compiles (2 s). The guest script's output lands in
# EXCHANGE_DIR/guest.log and its exit status in EXCHANGE_DIR/guest.status.
#
# Exit status: 0 when the VM ran the guest script (whatever the script's result), 77 when a
# prerequisite is missing (the caller reports a skip), anything else when preparing or booting
# failed.
set -euo pipefail

# The guest kernel is the Debian kernel whose headers are installed (setup.sh installs
# linux-headers-amd64, which follows bookworm's current kernel); FR_VM_KERNEL overrides it.
detect_kernel() {
  local d
  for d in $(ls -d /lib/modules/*-amd64/build 2>/dev/null | sort -V -r); do
    basename "$(dirname "$d")"; return
  done
}
readonly KVER=${FR_VM_KERNEL:-$(detect_kernel)}
readonly BOOT_TIMEOUT_S=${FR_VM_TIMEOUT_S:-840}

skip() {
  echo "SKIP: $*" >&2
  [[ -n ${exchange:-} && -d $exchange ]] && echo "$*" >"$exchange/skip-reason.txt"
  exit 77
}
die() { echo "ERROR: $*" >&2; exit 1; }

[[ $# -eq 3 || $# -eq 4 ]] || die "usage: $0 CACHE_DIR EXCHANGE_DIR GUEST_SCRIPT [FR_CLI]"
cache=$(realpath -m "$1")
exchange=$(realpath -m "$2")
guest_script=$(realpath "$3")
cli=${4:-face-reenact}
# Results of an earlier run must never be mistaken for this one's.
case $exchange in /|/tmp|/root|/home|/work|/usr|/etc) die "refusing to use '$exchange' as the exchange folder";; esac
rm -rf "$exchange" 2>/dev/null
mkdir -p "$exchange" 2>/dev/null || true   # a user who cannot create it is told below (skip)

# --- prerequisites: missing ones mean "cannot run here", not "broken" ------------------------
[[ -z ${FR_SKIP_VM_TEST:-} ]] || skip "FR_SKIP_VM_TEST is set"
[[ $(id -u) -eq 0 ]] || skip "needs root (qemu's 9p export of / and apt-get download)"
for tool in qemu-system-x86_64 cpio depmod gzip v4l2-ctl ffmpeg make; do
  command -v "$tool" >/dev/null || skip "'$tool' is not installed (apt-get install qemu-system-x86 cpio kmod v4l-utils ffmpeg make)"
done
busybox=""
for candidate in /bin/busybox /usr/bin/busybox; do
  if [[ -x $candidate ]] && file -L "$candidate" 2>/dev/null | grep -q "statically linked"; then
    busybox=$candidate; break
  fi
  # 'file' may be missing: busybox-static's binary has no ELF interpreter.
  if [[ -x $candidate ]] && ! command -v file >/dev/null && ! grep -q "ld-linux" "$candidate"; then
    busybox=$candidate; break
  fi
done
[[ -n $busybox ]] || skip "no static busybox (apt-get install busybox-static)"
[[ -n $KVER && -d /lib/modules/$KVER/build ]] || skip "no Debian kernel headers installed (apt-get install linux-headers-amd64)"
command -v clang >/dev/null || command -v gcc >/dev/null || skip "no C compiler to build v4l2loopback"

mkdir -p "$cache"
exec 9>"$cache/.lock"
flock 9   # two test runs share one cache

# --- packages: kernel image and v4l2loopback source (downloaded once) -------------------------
debs=$cache/debs
if [[ ! -f $debs/.done ]]; then
  mkdir -p "$debs"
  chmod 777 "$debs"   # apt-get download drops privileges to _apt for the download itself
  (cd "$debs" && apt-get download "linux-image-$KVER" v4l2loopback-dkms) \
    || skip "could not download linux-image-$KVER and v4l2loopback-dkms (no package mirror reachable?)"
  touch "$debs/.done"
fi

root=$cache/root   # the unpacked packages
if [[ ! -f $root/.done ]]; then
  rm -rf "$root"; mkdir -p "$root"
  for deb in "$debs"/*.deb; do dpkg -x "$deb" "$root"; done
  depmod -b "$root" "$KVER"
  touch "$root/.done"
fi

# --- the module, built from the dkms source against Debian's headers --------------------------
module=$cache/v4l2loopback.ko
if [[ ! -f $module ]]; then
  build=$cache/v4l2loopback-build
  src=$(ls -d "$root"/usr/src/v4l2loopback-* 2>/dev/null | sort -V | tail -1)
  [[ -n $src ]] || die "the v4l2loopback-dkms package holds no source folder"
  rm -rf "$build"; cp -r "$src" "$build"
  cc=gcc; command -v gcc >/dev/null || cc=clang
  make -s -C "/lib/modules/$KVER/build" M="$build" CC="$cc" modules >"$cache/module-build.log" 2>&1 \
    || { cat "$cache/module-build.log" >&2; die "building v4l2loopback failed"; }
  cp "$build/v4l2loopback.ko" "$module"
fi

# --- initramfs: busybox, the modules 9p needs, and an /init that runs the guest script ---------
initrd=$cache/initrd.gz
init_source=$(dirname "$(realpath "$0")")/guest_init.sh
if [[ ! -f $initrd || $init_source -nt $initrd || $module -nt $initrd ]]; then
  staging=$cache/initramfs
  rm -rf "$staging"; mkdir -p "$staging"/{bin,dev,proc,sys,host,modules}
  cp "$busybox" "$staging/bin/busybox"
  for name in mc videodev virtio_ring virtio virtio_pci_legacy_dev virtio_pci_modern_dev virtio_pci \
              9pnet 9pnet_virtio netfs fscache 9p sch_netem; do
    rel=$(grep -E "(^|/)$name\.ko(\.xz)?:" "$root/lib/modules/$KVER/modules.dep" | head -1 | cut -d: -f1)
    [[ -n $rel ]] || die "module $name not found in modules.dep of $KVER"
    cp "$root/lib/modules/$KVER/$rel" "$staging/modules/"
  done
  cp "$module" "$staging/modules/"
  cp "$init_source" "$staging/init"; chmod 755 "$staging/init"
  (cd "$staging" && find . | cpio -o -H newc --quiet | gzip -1) >"$initrd.tmp"
  mv "$initrd.tmp" "$initrd"
fi

# --- boot ------------------------------------------------------------------------------------
cp "$guest_script" "$exchange/guest.sh"
cp "$module" "$exchange/v4l2loopback.ko"   # the guest may reload it with other options
# Inside the guest the exchange folder is /tmp and the host's /tmp is /tmp/.host-tmp (guest_init.sh).
guest_path() { case $1 in /tmp/*) printf '/tmp/.host-tmp/%s' "${1#/tmp/}";; *) printf '%s' "$1";; esac; }
printf "FR_CLI='%s'\n" "$(guest_path "$cli")" >"$exchange/env.sh"
# Optional: a recording for the live-session webcam check (made by the CTest fixture vm_live_recording).
printf "FR_VM_LIVE_RECORDING='%s'\n" "$(guest_path "${FR_VM_LIVE_RECORDING:-}")" >>"$exchange/env.sh"
# Optional: the reenacted video and the page for the browser check (fixture vm_reenacted_video).
printf "FR_VM_REENACTED='%s'\n" "$(guest_path "${FR_VM_REENACTED:-}")" >>"$exchange/env.sh"
printf "FR_VM_TEST_DIR='%s'\n" "$(guest_path "$(dirname "$(realpath "$0")")")" >>"$exchange/env.sh"
# Software emulation (TCG) by default: on the build machines /dev/kvm exists but nested KVM
# hangs in the firmware or aborts on MSRs, and TCG boots in seconds. FR_VM_KVM=1 opts in.
accels=("tcg")
if [[ -n ${FR_VM_KVM:-} && -r /dev/kvm && -w /dev/kvm ]]; then accels=("kvm" "tcg"); fi
for accel in "${accels[@]}"; do
  echo "booting $KVER (accel=$accel), guest script $(basename "$guest_script")"
  set +e
  timeout --kill-after=10 "$BOOT_TIMEOUT_S" qemu-system-x86_64 -machine accel="$accel" -m 2048 -smp 2 \
    -nographic -no-reboot -kernel "$root/boot/vmlinuz-$KVER" -initrd "$initrd" \
    -virtfs local,path=/,mount_tag=host,security_model=none,readonly=on,multidevs=remap \
    -virtfs local,path="$exchange",mount_tag=exchange,security_model=none,multidevs=remap \
    -append "console=ttyS0 quiet panic=-1" >"$exchange/console.log" 2>&1
  qemu_status=$?
  set -e
  if [[ $qemu_status -eq 124 || $qemu_status -eq 137 ]]; then
    tail -40 "$exchange/console.log" >&2
    die "the VM did not finish within ${BOOT_TIMEOUT_S}s"
  fi
  [[ -f $exchange/guest.status ]] && break
  echo "qemu (accel=$accel) exited $qemu_status before the guest script ran:" >&2
  tail -5 "$exchange/console.log" >&2
done
[[ -f $exchange/guest.status ]] || die "the guest script did not run"
echo "guest script exit status: $(cat "$exchange/guest.status")"
exit 0
