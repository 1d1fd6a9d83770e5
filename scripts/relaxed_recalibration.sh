#!/usr/bin/env bash
# The calibration again on the most relaxed frames (TrackerOptions::relaxed_recalibration_frames)
# on every shared real clip (../shared/data/videos): one table row per clip with the first
# calibration's strongest neutral weight, the frames the watch kept, the second calibration's and
# whether it was kept, and what it did to the fit's agreement with the detector on the frames after
# it (against the same run with --relaxed-recalibration 0). docs/tracking-pipeline.md
# ("Calibrating again on the most relaxed frames") measures with it.
# Usage: scripts/relaxed_recalibration.sh OUT_DIR [FRAMES]   (run from the repository; FRAMES 150)
set -euo pipefail
OUT="${1:?usage: $0 OUT_DIR [FRAMES]}"
FRAMES="${2:-150}"
source "$(dirname "${BASH_SOURCE[0]}")/real_clips.sh"
mkdir -p "$OUT"
echo "| clip | first neutral (strongest) | warning before | frames kept | neutral after | warning after | inner NME after, off -> on | pose off the PnP after, off -> on (deg) |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- |"
for clip in "${REAL_CLIPS[@]}"; do
  name="${clip%.*}"
  for mode in on off; do
    extra=()
    [ "$mode" = off ] && extra=(--relaxed-recalibration 0)
    "$FR" track --input "$VIDEOS/$clip" --frames "$FRAMES" --out "$OUT/$name.$mode.jsonl" \
          --report "$OUT/$name.$mode.json" --quiet "${extra[@]}"
  done
  python3 - "$OUT/$name" "$name" <<'PY'
import json, sys
base, name = sys.argv[1], sys.argv[2]
on, off = json.load(open(base + ".on.json")), json.load(open(base + ".off.json"))
neutral = off["neutral"]["expression"] if off.get("neutral") else []
rr = on["relaxed_recalibration"]
def after(kind, start):
    rows = [json.loads(l) for l in open(base + "." + kind + ".jsonl")]
    rows = [r for r in rows if r["frame"] >= start and r.get("agreement") and r["agreement"].get("landmark_nme") is not None]
    if not rows: return None, None
    return (sum(r["agreement"]["landmark_nme"] for r in rows) / len(rows),
            sum(r["agreement"]["pose_disagreement_deg"] for r in rows) / len(rows))
if rr is None:
    print("| %s | %s | %s | (no watch) | | %s | | |" % (name, "below the trigger" if off["calibrated"] else "not calibrated",
          "yes" if off["calibration_warning"] else "no", "yes" if on["calibration_warning"] else "no"))
else:
    # From the frame after the second calibration applied (the second "calibrated" status).
    calibrated = [json.loads(l)["frame"] for l in open(base + ".on.jsonl") if '"status":"calibrated"' in l.replace(" ", "")]
    start = (calibrated[1] if len(calibrated) > 1 else calibrated[-1]) + 1
    n_off, p_off = after("off", start)
    n_on, p_on = after("on", start)
    fmt = lambda a, b, f: (f % a) + " -> " + (f % b) if a is not None and b is not None else "?"
    print("| %s | %.2f | %s | %s | %s | %s | %s | %s |" % (
        name, rr["first_weight"], "yes" if off["calibration_warning"] else "no",
        ", ".join(str(f) for f in rr["frames"]) or "none",
        ("%.2f (%s)" % (rr["relaxed_weight"], "kept" if rr["recalibrated"] else "not kept")) if rr["frames"] else "-",
        "yes" if on["calibration_warning"] else "no",
        fmt(n_off, n_on, "%.4f") if rr["recalibrated"] else "-", fmt(p_off, p_on, "%.1f") if rr["recalibrated"] else "-"))
PY
done
