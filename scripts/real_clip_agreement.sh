#!/usr/bin/env bash
# The fit against its own landmarks on every shared real clip (../shared/data/videos), one table
# row per clip: docs/tracking-pipeline.md ("No silent failures") and docs/real-time.md measure with
# it. Extra arguments go to every `track` run (e.g. `--tracking-tolerance 0` for the paper's whole
# schedule, to compare a speed-up's cost in accuracy in one sitting).
# Usage: scripts/real_clip_agreement.sh OUT_DIR [FRAMES] [-- TRACK_ARGS...]   (run from the repository)
set -euo pipefail
OUT="${1:?usage: $0 OUT_DIR [FRAMES] [-- TRACK_ARGS...]}"
FRAMES="${2:-300}"
shift $(( $# >= 2 ? 2 : 1 ))
[ "${1:-}" = "--" ] && shift
source "$(dirname "${BASH_SOURCE[0]}")/real_clips.sh"
mkdir -p "$OUT"
echo "| clip (frames) | pose off the landmarks' median / p95 / max, deg | beyond 15 deg | inner-point NME median / p95 | beyond 5 % | lost | GN iterations per frame | synthesis + analysis ms per frame | field of view |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
for clip in "${REAL_CLIPS[@]}"; do
  name="${clip%.*}"
  "$FR" track --input "$VIDEOS/$clip" --frames "$FRAMES" --out "$OUT/$name.params.jsonl" \
        --report "$OUT/$name.track.json" --quiet "$@"
  python3 - "$OUT/$name.track.json" "$name" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
a = r["agreement"]
pose, nme = a["pose_disagreement_deg"], a["landmark_nme"]
beyond = a["fit_frames_beyond"]
cam = r.get("camera", {})
fov = cam.get("horizontal_fov_deg")
print("| %s (%d) | %.1f / %.1f / %.1f | %d | %.1f / %.1f %% | %d | %d | %.1f | %.1f | %s |" % (
    sys.argv[2], r["frames"], pose["median"], pose["p95"], pose["max"], beyond["pose"],
    100 * nme["median"], 100 * nme["p95"], beyond["landmarks"], r["statuses"].get("lost", 0),
    r["gauss_newton_iterations_per_frame"], r["synthesis_ms"] + r["analysis_ms"],
    "%.1f deg (%s)" % (fov, cam.get("from", "?")) if fov is not None else "?"))
PY
done
