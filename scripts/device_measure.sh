#!/usr/bin/env bash
# The GPU measurements of issue #27, run ON a lent GPU machine from the bundle that
# scripts/device_bundle.py made (docs/real-time.md, "On a GPU"). Each step's whole output goes to
# $OUT/<step>.log; a short summary is printed last.
#
#   scripts/device_measure.sh unpack            # .device/bundle.tar.xz -> /tmp/fr
#   scripts/device_measure.sh dlib              # .device/dlib.xz.* (one or both parts) -> /tmp/fr
#   scripts/device_measure.sh track [FRAMES]    # bench track at 640x480 and 1280x960, every strategy
#                                               # (and the baseline program's, when bundled)
#   scripts/device_measure.sh compare [FRAMES]  # this build against the bundled baseline (bench track,
#                                               # the paper's whole schedule and the tracker's 3 %)
#   scripts/device_measure.sh renderers CLIP PARAMS [S]  # bench live reenact, CPU against Vulkan renderer
#   scripts/device_measure.sh render [FRAMES]   # bench reenact, this build against the baseline (A B A B)
#   scripts/device_measure.sh live CLIP [S]     # bench live on CLIP: passthrough with each solver
#   scripts/device_measure.sh udp CLIP ACTOR [S]  # bench live --mode reenact, ACTOR's expressions over UDP
#   scripts/device_measure.sh ahead CLIP PARAMS [S]  # bench live, the landmark stage off and on (A B A B)
#   scripts/device_measure.sh reenact SRC TGT [N] # reenact N frames, both actors tracked, each solver,
#                                                 # with contact sheets in $OUT/sheets_<solver>
set -uo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
FR=/tmp/fr
OUT="${OUT:-/tmp/fr-out}"
mkdir -p "$OUT"
export LD_LIBRARY_PATH="$FR/lib"
# The NVIDIA driver's Vulkan ICD on the lent machines (/work/.library/device/README.md).
if [ -f /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ]; then
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
fi
fr() { "$FR/bin/face-reenact" "$@"; }

# bench live runs on CLIP, PARAMS' expressions replayed over UDP at 30 Hz to the reenact runs; each
# RUN is "MODE LANDMARKS_AHEAD(on|off) RENDERER ROUND". Every run's whole output goes to $OUT/LOG.
live_runs() {
  local log="$1" clip="$2" params="$3" seconds="$4"
  shift 4
  export FACE_REENACT_SHAPE_PREDICTOR="$FR/shape_predictor_68_face_landmarks.dat"
  export FACE_REENACT_MODEL="$FR/bin/face-model.frm"
  [ -f "$FR/key" ] || fr keygen --out "$FR/key" >/dev/null
  fr send --to 127.0.0.1:9123 --key "$FR/key" --replay "$params" --rate 30 --loop >/dev/null 2>&1 &
  local sender=$! run
  for run in "$@"; do
    set -- $run
    local source_args=() ahead_args=()
    [ "$1" = reenact ] && source_args=(--source udp://9123 --key "$FR/key")
    [ "$2" = on ] && ahead_args=(--landmarks-ahead)
    echo "== bench live $1, landmarks ahead $2, renderer $3, round $4" | tee -a "$OUT/$log"
    fr bench live --target "$clip" --mode "$1" "${source_args[@]}" "${ahead_args[@]}" --renderer "$3" \
        --warmup 8 --seconds "$seconds" >"$OUT/run.log" 2>&1
    echo "(rc $?)" | tee -a "$OUT/$log"
    cat "$OUT/run.log" >>"$OUT/$log"
    grep -E "tracker solver|output .* fps|frames:|landmarks  |synthesis|analysis|gaze|render  |composite|hand-off|total  |cores busy|fr-live" \
        "$OUT/run.log"
  done
  rm -f "$OUT/run.log"
  kill "$sender"
}

case "${1:-}" in
  unpack)
    # The GL/EGL dispatch libraries the NVIDIA Vulkan driver loads itself (without them its ICD
    # gives no vkCreateInstance): Debian's, fetched here with `apt-get download` into .gl/
    # (/work/.library/device/README.md), unpacked into / on the device.
    for deb in "$ROOT"/.gl/*.deb; do [ -f "$deb" ] && dpkg -x "$deb" /; done
    ldconfig
    mkdir -p "$FR"
    tar -xJf "$ROOT/.device/bundle.tar.xz" -C "$FR"
    nvidia-smi --query-gpu=name,driver_version,clocks.sm,clocks.mem,utilization.gpu --format=csv | tee "$OUT/gpu.log"
    nproc | tee -a "$OUT/gpu.log"
    ls /usr/local/nvidia/share/vulkan/icd.d /usr/share/vulkan/icd.d /etc/vulkan/icd.d 2>/dev/null | tee -a "$OUT/gpu.log"
    fr devices 2>&1 | tee -a "$OUT/gpu.log"
    ;;
  dlib)
    # Parts arrive over two calls; the second call finds the first in /tmp/fr. Once the parts
    # make a whole xz stream, it is unpacked.
    for part in "$ROOT"/.device/dlib.xz.*; do [ -f "$part" ] && cp "$part" "$FR/"; done
    if cat "$FR"/dlib.xz.a? | xz -t 2>/dev/null; then
      cat "$FR"/dlib.xz.a? | xz -d > "$FR/shape_predictor_68_face_landmarks.dat" && rm -f "$FR"/dlib.xz.a?
    fi
    ls -l "$FR"
    ;;
  track)
    frames="${2:-12}"
    programs=(face-reenact)
    [ -x "$FR/bin/face-reenact-baseline" ] && programs+=(face-reenact-baseline)
    for size in "640 480" "1280 960"; do
      for program in "${programs[@]}"; do
        set -- $size
        log="$OUT/track_${program}_${1}x${2}.log"
        "$FR/bin/$program" bench track --model "$FR/bin/face-model.frm" --frames "$frames" --width "$1" --height "$2" \
            >"$log" 2>&1
        echo "== $program: bench track ${1}x${2}, $frames frames (rc $?)"
        grep -E "total per frame|vulkan device|CPU reference|auto:|calibration" "$log"
      done
    done
    # Per-submission GPU times of one short run (timestamp queries; the NVIDIA driver's are real).
    FR_TRACKER_PROFILE=1 fr bench track --model "$FR/bin/face-model.frm" --frames 3 --vulkan matrix-free \
        >"$OUT/track_profile.log" 2>&1
    grep "^tracker" "$OUT/track_profile.log" | tail -12
    ;;
  compare)
    # This program against the bundled baseline, alternating (A B A B) at 640x480, then one run
    # with the per-submission GPU times (FR_TRACKER_PROFILE=1).
    # Both schedules: the paper's whole one (tolerance 0) and the tracker's (3 %).
    frames="${2:-8}"
    for tolerance in 0 0.03; do
      for round in 1 2; do
        for program in face-reenact face-reenact-baseline; do
          log="$OUT/compare_${program}_${tolerance}_${round}.log"
          "$FR/bin/$program" bench track --model "$FR/bin/face-model.frm" --frames "$frames" --vulkan matrix-free \
              --tracking-tolerance "$tolerance" >"$log" 2>&1
          echo "== $program, tolerance $tolerance, round $round (rc $?)"
          grep -E "^(vulkan_matrix_free|cpu_matrix_free) .*total per frame|submissions" "$log"
        done
      done
    done
    FR_TRACKER_PROFILE=1 timeout 120 "$FR/bin/face-reenact" bench track --model "$FR/bin/face-model.frm" --frames 3 \
        --vulkan matrix-free >"$OUT/track_profile.log" 2>&1
    grep "^tracker" "$OUT/track_profile.log" | tail -12
    ;;
  renderers)
    # bench live --mode reenact on CLIP with the CPU and the Vulkan renderer, alternating (A B A B).
    live_runs renderers.log "$2" "$3" "${4:-10}" "reenact off cpu 1" "reenact off vulkan 1" "reenact off cpu 2" \
        "reenact off vulkan 2"
    ;;
  render)
    # bench reenact (re-render, mouth, composite; the CPU and the Vulkan rasteriser) at 640x480
    # and 1280x960, this build against the bundled baseline, alternating (A B A B).
    frames="${2:-60}"
    for size in 640x480 1280x960; do
      for round in 1 2; do
        for program in face-reenact face-reenact-baseline; do
          "$FR/bin/$program" bench reenact --model "$FR/bin/face-model.frm" --size "$size" --frames "$frames" \
              >"$OUT/run.log" 2>&1
          echo "== $program, bench reenact $size, round $round (rc $?)" | tee -a "$OUT/render.log"
          cat "$OUT/run.log" >>"$OUT/render.log"
          grep -E "^(cpu|vulkan) " "$OUT/run.log"
        done
      done
    done
    rm -f "$OUT/run.log"
    ;;
  live)
    clip="$2"
    seconds="${3:-15}"
    export FACE_REENACT_SHAPE_PREDICTOR="$FR/shape_predictor_68_face_landmarks.dat"
    export FACE_REENACT_MODEL="$FR/bin/face-model.frm"
    for solver in vulkan cpu; do
      for renderer in cpu vulkan; do
        log="$OUT/live_${solver}_${renderer}.log"
        fr bench live --target "$clip" --mode passthrough --solver "$solver" --renderer "$renderer" \
            --warmup 8 --seconds "$seconds" >"$log" 2>&1
        echo "== bench live passthrough, solver $solver, renderer $renderer (rc $?)"
        grep -E "tracker solver|output .* fps|frames:|analysis|synthesis|landmarks|render|composite|total|cores busy" "$log"
      done
    done
    ;;
  udp)
    # bench live --mode reenact with the source actor's expressions arriving over UDP, as the OBS
    # source and the webcam get them (docs/real-time.md), every setting at its default.
    export FACE_REENACT_SHAPE_PREDICTOR="$FR/shape_predictor_68_face_landmarks.dat"
    export FACE_REENACT_MODEL="$FR/bin/face-model.frm"
    clip="$2" actor="$3" seconds="${4:-12}"
    fr keygen --out "$FR/key" >/dev/null
    fr track --input "$actor" --out "$FR/actor.jsonl" --quiet >"$OUT/udp_track.log" 2>&1
    fr send --to 127.0.0.1:9123 --key "$FR/key" --replay "$FR/actor.jsonl" --rate 30 --loop >/dev/null 2>&1 &
    sender=$!
    fr bench live --target "$clip" --mode reenact --source udp://9123 --key "$FR/key" --warmup 8 --seconds "$seconds" \
        >"$OUT/live_udp.log" 2>&1
    echo "== bench live reenact, expressions over UDP (rc $?)"
    kill "$sender"
    grep -E "tracker solver|Tracking|output .* fps|frames:|landmarks|synthesis|analysis|gaze|render  |composite|total  |cores busy" \
        "$OUT/live_udp.log"
    ;;
  ahead)
    # The landmark stage (LiveSession::Options::landmarks_ahead) off and on, alternating, two rounds:
    # bench live passthrough and reenact on CLIP; then reenact with the Vulkan renderer.
    runs=()
    for round in 1 2; do
      for mode in passthrough reenact; do
        for ahead in off on; do runs+=("$mode $ahead cpu $round"); done
      done
    done
    live_runs ahead.log "$2" "$3" "${4:-10}" "${runs[@]}" "reenact on vulkan 3"
    ;;
  reenact)
    export FACE_REENACT_SHAPE_PREDICTOR="$FR/shape_predictor_68_face_landmarks.dat"
    frames="${4:-120}"
    for solver in vulkan cpu; do
      log="$OUT/reenact_${solver}.log"
      start=$(date +%s%N)
      fr reenact --model "$FR/bin/face-model.frm" --source "$2" --target "$3" --frames "$frames" --solver "$solver" \
          --out "/tmp/reenact_${solver}.mp4" --report "$OUT/reenact_${solver}.json" --sheets "$OUT/sheets_${solver}" \
          >"$log" 2>&1
      rc=$?
      echo "== reenact $frames frames, solver $solver (rc $rc): $(( ($(date +%s%N) - start) / 1000000 )) ms wall"
      tail -3 "$log"
    done
    ;;
  *)
    sed -n 2,12p "$0"
    exit 2
    ;;
esac
