# Sourced by the real-clip scripts (real_clip_agreement.sh, real_clip_sheets.sh,
# relaxed_recalibration.sh): where the program and the shared clips are, and the clips they go over.
# Sets ROOT (the repository), FR (the program: $FR_CLI or the build's), VIDEOS
# (../shared/data/videos beside the repository; exits when it is not there) and REAL_CLIPS.
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
FR="${FR_CLI:-$ROOT/build/bin/face-reenact}"
VIDEOS="$ROOT/../shared/data/videos"
[ -d "$VIDEOS" ] || { echo "no $VIDEOS: the shared real clips are not beside this clone" >&2; exit 1; }
REAL_CLIPS=(webcam_talking_640x480.wmv liveportrait_d14.mp4 liveportrait_d12.mp4 liveportrait_d0.mp4
            liveportrait_d6.mp4 liveportrait_d10.mp4 multi_face.avi)
