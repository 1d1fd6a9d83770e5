#!/bin/bash
# The reenacted video that the VM's browser check sends through the virtual webcam (CTest fixture
# vm_reenacted_video): two synthetic actors (320x240, 24 frames, different identities) and
# `face-reenact reenact` of one onto the other, made on the host, where it takes seconds (under the
# VM's software emulation the calibration alone takes many minutes). The status log says which
# output frames are reenacted and which are the target unchanged while it calibrates.
#
#   make_reenacted_video.sh FACE_REENACT MODEL OUT_DIR
set -euo pipefail
cli=$1 model=$2 out=$3
rm -rf "$out"
mkdir -p "$out"
"$cli" synth --size 320x240 --frames 24 --seed 7 --quiet --overwrite --model "$model" --out "$out/target"
"$cli" synth --size 320x240 --frames 24 --seed 11 --quiet --overwrite --model "$model" --out "$out/source"
"$cli" reenact --source "$out/source" --target "$out/target" --landmarks recording --model "$model" \
  --out "$out/reenacted.mp4" --status-log "$out/status.jsonl" --quiet
