#!/usr/bin/env bash
# Contact sheets on the shared real clips (../shared/data/videos), for a person to look at:
#   - the fit drawn over each clip (`track --overlay`), three frames side by side;
#   - a reenactment (`reenact --sheets`: source | target | output, the faces and the mouth zoomed), with the
#     report and the per-frame statuses beside it.
# Usage: scripts/real_clip_sheets.sh OUT_DIR [FRAMES]   (needs ffmpeg; run from the repository)
set -euo pipefail
OUT="${1:?usage: $0 OUT_DIR [FRAMES]}"
FRAMES="${2:-150}"
source "$(dirname "${BASH_SOURCE[0]}")/real_clips.sh"
mkdir -p "$OUT"

# Three frames of a video, side by side (half size), into a PNG.
sheet() {  # sheet VIDEO OUT.png FRAME FRAME FRAME
  local video="$1" png="$2"
  ffmpeg -loglevel error -y -i "$video" \
    -vf "select='eq(n\,$3)+eq(n\,$4)+eq(n\,$5)',scale=iw/2:ih/2,tile=3x1" -frames:v 1 "$png"
}

for clip in webcam_talking_640x480.wmv liveportrait_d14.mp4 liveportrait_d12.mp4 multi_face.avi; do
  name="${clip%.*}"
  "$FR" track --input "$VIDEOS/$clip" --frames "$FRAMES" --out "$OUT/$name.params.jsonl" \
        --report "$OUT/$name.track.json" --overlay "$OUT/$name.overlay.mp4" --quiet
  sheet "$OUT/$name.overlay.mp4" "$OUT/$name.overlay.png" $((FRAMES / 5)) $((FRAMES / 2)) $((FRAMES - 5))
done

# The reenactment: a LivePortrait driving clip onto the webcam clip (paired by time).
src="$VIDEOS/liveportrait_d14.mp4" tgt="$VIDEOS/webcam_talking_640x480.wmv"
"$FR" reenact --source "$src" --target "$tgt" --frames "$FRAMES" --out "$OUT/reenact.mp4" \
      --report "$OUT/reenact.json" --status-log "$OUT/reenact.status.jsonl" --quiet \
      --sheets "$OUT" --sheet-frames "$((FRAMES / 3)),$((2 * FRAMES / 3)),$((FRAMES - 5))"
# The brows and the light (docs/tracker.md "Brows", docs/reenactment.md "Appearance"): d14's raise (output frame 36),
# frown (59), and frame 172, after the camera's exposure dropped at 126-150 (the tracked light drifted red).
mkdir -p "$OUT/brows"
"$FR" reenact --source "$src" --target "$tgt" --frames 175 --out "$OUT/brows.mp4" --quiet \
      --sheets "$OUT/brows" --sheet-frames 36,59,172
# Closed lids (docs/reenactment.md, "Lids the output closes"): d14 smiling with her eyes shut at output frames 75 and
# 95 (the webcam clip at 15 fps), the eyes 4x (lids.png, lids_95.png: target | output); on d12 (glasses) at its frame
# 125 too.
mkdir -p "$OUT/lids"
"$FR" reenact --source "$src" --target "$tgt" --frames 100 --out "$OUT/lids/webcam.mp4" --quiet --frames-dir "$OUT/lids/webcam" \
      --sheets "$OUT/lids" --sheet-frames 75,95
ffmpeg -loglevel error -y -i "$tgt" -i "$OUT/lids/webcam/frame_000019.png" -i "$OUT/lids/webcam/frame_000020.png" \
       -i "$OUT/lids/webcam/frame_000053.png" -filter_complex \
       "[0]select='eq(n\,19)+eq(n\,20)+eq(n\,53)',crop=150:40:170:198,scale=450:120:flags=neighbor,tile=3x1[a];$(for k in 1 2 3; do
          printf '[%d]crop=150:40:170:198,scale=450:120:flags=neighbor[b%d];' $k $k; done)[b1][b2][b3]hstack=3[b];[a][b]vstack" \
       -frames:v 1 "$OUT/eyes_webcam.png"
ffmpeg -loglevel error -y -ss 0 -i "$tgt" -i "$OUT/lids/webcam/frame_000075.png" -filter_complex \
       "[0]select='eq(n\,75)',crop=160:60:245:175,scale=640:240:flags=neighbor[a];[1]crop=160:60:245:175,scale=640:240:flags=neighbor[b];[a][b]vstack" \
       -frames:v 1 "$OUT/lids.png"
ffmpeg -loglevel error -y -ss 0 -i "$tgt" -i "$OUT/lids/webcam/frame_000095.png" -filter_complex \
       "[0]select='eq(n\,95)',crop=200:70:200:170,scale=800:280:flags=neighbor[a];[1]crop=200:70:200:170,scale=800:280:flags=neighbor[b];[a][b]vstack" \
       -frames:v 1 "$OUT/lids_95.png"
# The same lids side by side (target | output; output frames 75, 89, 95), each crop around both eyes: the lids take
# the colour of the target's own blink at its frames 19-20 (docs/reenactment.md, "The lids a blink shows"); run once
# more with FR_CLI set to an earlier build to put a before beside it.
lid_row() {  # lid_row FRAME X Y OUT.png
  ffmpeg -loglevel error -y -i "$tgt" -i "$OUT/lids/webcam/$(printf frame_%06d.png "$1")" -filter_complex \
         "[0]select='eq(n\,$1)',crop=200:70:$2:$3,scale=400:140[a];[1]crop=200:70:$2:$3,scale=400:140[b];[a][b]hstack" \
         -frames:v 1 "$4"
}
lid_row 75 200 170 "$OUT/lids/row75.png"; lid_row 89 230 175 "$OUT/lids/row89.png"; lid_row 95 220 170 "$OUT/lids/row95.png"
ffmpeg -loglevel error -y -i "$OUT/lids/row75.png" -i "$OUT/lids/row89.png" -i "$OUT/lids/row95.png" \
       -filter_complex vstack=3 "$OUT/lids_rows.png"
"$FR" reenact --source "$src" --target "$VIDEOS/liveportrait_d12.mp4" --frames 130 --out "$OUT/lids/d12.mp4" --quiet \
      --sheets "$OUT/lids/d12" --sheet-frames 125
# Thin dark lines drawn whole (docs/reenactment.md, "The lids a blink shows", "The slit of a barely parted mouth,
# unbroken"): d14's shut eyes at output frames 69-71, the eyes 3x, target above output (lash_line.png: one lash line
# in his lashes' red-brown, no dots), and her barely parted lips at 34, 36, 38 and 40, the mouth 3x (slit.png: one thin
# line between the lips, not dashes that move from frame to frame).
crops_row() {  # crops_row CROP OUT.png FRAME... : the target's frames above the output's
  local crop="$1" png="$2" inputs=() filter="" k=0
  shift 2
  for f in "$@"; do inputs+=(-i "$OUT/lids/webcam/$(printf frame_%06d.png "$f")"); done
  local select
  select="$(printf "+eq(n\\,%d)" "$@")"
  filter="[0]select='${select#+}',$crop,tile=$#x1[a];"
  for f in "$@"; do k=$((k + 1)); filter+="[$k]$crop[b$k];"; done
  for k in $(seq 1 $#); do filter+="[b$k]"; done
  ffmpeg -loglevel error -y -i "$tgt" "${inputs[@]}" -filter_complex "${filter}hstack=$#[b];[a][b]vstack" \
         -frames:v 1 "$png"
}
crops_row "crop=140:40:230:190,scale=420:120:flags=neighbor" "$OUT/lash_line.png" 69 70 71
crops_row "crop=100:50:200:275,scale=300:150:flags=neighbor" "$OUT/slit.png" 34 36 38 40

# A mouth the output opens less than the target's (docs/reenactment.md): d6 baring clenched teeth onto d12's wide-open
# mouth, output frame 125 (the sheet's mouth zoom; before, a grey-green band of the map's teeth along the lower lip).
mkdir -p "$OUT/mouth_less"
"$FR" reenact --source "$VIDEOS/liveportrait_d6.mp4" --target "$VIDEOS/liveportrait_d12.mp4" --frames 130 \
      --out "$OUT/mouth_less/d12.mp4" --quiet --sheets "$OUT/mouth_less" --sheet-frames 40,80,125
# A source baring her teeth with the lips pulled apart onto an actor filmed from below (docs/reenactment.md, "Farther
# past the polygon, where the inside continues", "Teeth pushed through the skin", and the albedo texture's pitched front
# view): d6 onto d10, output frames 109 and 120 (the mouth zoom: no grey-green strokes beside the lower lip, no pale
# blob on the chin).
mkdir -p "$OUT/bared_teeth"
"$FR" reenact --source "$VIDEOS/liveportrait_d6.mp4" --target "$VIDEOS/liveportrait_d10.mp4" --frames 125 \
      --out "$OUT/bared_teeth/d10.mp4" --quiet --sheets "$OUT/bared_teeth" --sheet-frames 109,120 \
      --frames-dir "$OUT/bared_teeth/d10"
# The eyes (docs/reenactment.md, "Lids the output lowers part way, a gaze turned hard aside", "The eye's real
# opening"): the same run's output frames 30, 100 and 120 (d6 squinting and looking aside) and 114, 116 (d6 crossing her
# eyes while d10 narrows hers: one iris per eye, turned, no rings), the eyes 3x, target above output (eyes.png: no pale
# band or reddish line along the lowered lids, no pink patch on the white); and the webcam clip's frames 19, 20 (he
# blinks, d14's eyes open: drawn from his open eyes) and 53 (d14 looking hard aside: the bared white in the camera's dim
# grey, not a bright wedge) from the lids run, target above output (eyes_webcam.png).
eyes=()
eye_frames=(30 100 114 116 120)
for f in "${eye_frames[@]}"; do eyes+=(-i "$VIDEOS/liveportrait_d10.mp4" -i "$OUT/bared_teeth/d10/frame_$(printf %06d "$f").png"); done
ffmpeg -loglevel error -y "${eyes[@]}" -filter_complex \
       "$(for k in 0 1 2 3 4; do
          printf "[%d]select='eq(n\\,%d)',crop=200:56:160:205,scale=600:168:flags=neighbor[a%d];[%d]crop=200:56:160:205,scale=600:168:flags=neighbor[b%d];" \
                 $((2 * k)) "${eye_frames[$k]}" $k $((2 * k + 1)) $k
        done)[a0][b0][a1][b1][a2][b2][a3][b3][a4][b4]vstack=10" -frames:v 1 "$OUT/eyes.png"
# The closed loop on real video (docs/reenactment.md, "Measured", "On real video"): each driving clip onto the webcam
# clip, the output tracked again; and the albedo map's pass-through fidelity. Figures in closed_loop_*.json.
for s in d14 d6 d0; do
  "$FR" reenact --source "$VIDEOS/liveportrait_$s.mp4" --target "$tgt" --frames 150 --closed-loop \
        --out "$OUT/closed_loop_$s.mp4" --report "$OUT/closed_loop_$s.json" --quiet
done
"$FR" reenact --source "$tgt" --target "$tgt" --frames 150 --mode pass-through --appearance albedo-map --closed-loop \
      --out "$OUT/closed_loop_pass_through.mp4" --report "$OUT/closed_loop_pass_through.json" --quiet
# The mouth interior (docs/reenactment.md, "Mouth"): the longest driving clip onto the whole webcam clip, whose
# speaker opens the mouth wide facing the camera at frame 256; the same with the model's teeth and cavity beside it.
for mouth in auto model; do
  mkdir -p "$OUT/mouth_$mouth"
  "$FR" reenact --source "$VIDEOS/liveportrait_d6.mp4" --target "$tgt" --out "$OUT/mouth_$mouth.mp4" \
        --report "$OUT/mouth_$mouth.json" --quiet --mouth "$mouth" --sheets "$OUT/mouth_$mouth" --sheet-frames 120,270,280
done
# The source actor's mouth standing in (docs/reenactment.md, "The source actor's mouth"): d6 onto the webcam clip, whose
# speaker keeps his mouth shut until frame 256; output frames 30, 45, 60 and 85, the mouth 3x: `--mouth target` (the
# model's teeth, textured) on top, the default (d6's own mouth in his light) below (mouth_source.png). The top row is
# also "Light through the opening": at frame 60 the model's tongue lit by the opening's size and depth, not a flat gash.
for mouth in target auto; do
  "$FR" reenact --source "$VIDEOS/liveportrait_d6.mp4" --target "$tgt" --frames 90 --out "$OUT/mouth_source_$mouth.mp4" \
        --quiet --mouth "$mouth" --frames-dir "$OUT/mouth_source_$mouth"
done
crops=()
for mouth in target auto; do
  for f in 30 45 60 85; do crops+=(-i "$OUT/mouth_source_$mouth/frame_0000$f.png"); done
done
ffmpeg -loglevel error -y "${crops[@]}" -filter_complex \
       "$(for k in 0 1 2 3 4 5 6 7; do printf '[%d]crop=140:90:180:250,scale=420:270:flags=neighbor[c%d];' $k $k; done)[c0][c1][c2][c3][c4][c5][c6][c7]xstack=inputs=8:layout=0_0|w0_0|w0+w1_0|w0+w1+w2_0|0_h0|w0_h0|w0+w1_h0|w0+w1+w2_h0" \
       "$OUT/mouth_source.png"
# Eyes turned where the target's are not (docs/reenactment.md, "The eye's real opening"): the same run (the default),
# output frames 44, 51, 53 and 55, d6 crossing her eyes and glancing aside onto his eyes looking ahead, the eyes 3x, target
# above output (eyes_turned.png: the eye within his own lids, no white over them, no dark crescent under the lower lid).
turned=()
for f in 44 51 53 55; do turned+=(-i "$tgt" -i "$OUT/mouth_source_auto/frame_0000$f.png"); done
ffmpeg -loglevel error -y "${turned[@]}" -filter_complex \
       "$(k=0; for f in 44 51 53 55; do
          printf "[%d]select='eq(n\\,%d)',crop=150:40:170:198,scale=450:120:flags=neighbor[a%d];[%d]crop=150:40:170:198,scale=450:120:flags=neighbor[b%d];" \
                 $((2 * k)) $f $k $((2 * k + 1)) $k; k=$((k + 1))
        done)[a0][b0][a1][b1][a2][b2][a3][b3]vstack=8" -frames:v 1 "$OUT/eyes_turned.png"
# A source filmed from below lends its mouth (docs/reenactment.md, "The source actor's mouth"): d10 (pitched 17-28
# degrees) onto the webcam clip, output frames 40 and 80 (mouth_from_below/sheet_*.png: teeth and tongue, no dark gash).
mkdir -p "$OUT/mouth_from_below"
"$FR" reenact --source "$VIDEOS/liveportrait_d10.mp4" --target "$tgt" --frames 90 --out "$OUT/mouth_from_below/out.mp4" \
      --quiet --sheets "$OUT/mouth_from_below" --sheet-frames 40,80
# A closed mouth's seam (docs/reenactment.md, "A closed mouth's seam"): d6 pressing her lips onto the webcam clip's
# closed mouth, output frame 120, the mouth 4x, target above output (seam.png: one soft line like the target's, no
# dashes).
"$FR" reenact --source "$VIDEOS/liveportrait_d6.mp4" --target "$tgt" --frames 122 --out "$OUT/seam.mp4" --quiet \
      --frames-dir "$OUT/seam"
ffmpeg -loglevel error -y -i "$tgt" -i "$OUT/seam/frame_000120.png" -filter_complex \
       "[0]select='eq(n\,120)',crop=110:50:225:245,scale=440:200:flags=neighbor[a];[1]crop=110:50:225:245,scale=440:200:flags=neighbor[b];[a][b]vstack" \
       -frames:v 1 "$OUT/seam.png"
# The source's folds and wrinkles (docs/reenactment.md, "Detail transfer"), each pair without and with the transfer.
mkdir -p "$OUT/detail"
detail_runs() {  # detail_runs SOURCE_CLIP FRAMES NAME: $OUT/detail/NAME_{off,transient}/frame_*.png
  for detail in off transient; do
    "$FR" reenact --source "$VIDEOS/$1" --target "$tgt" --frames "$2" --out "$OUT/detail/$3_$detail.mp4" \
          --quiet --detail "$detail" --frames-dir "$OUT/detail/$3_$detail"
  done
}
detail_difference() {  # detail_difference NAME FRAME CROP OUT.png: off | transient | their difference x4 around mid-grey
  local f; f=$(printf frame_%06d.png "$2")
  ffmpeg -loglevel error -y -i "$OUT/detail/$1_off/$f" -i "$OUT/detail/$1_transient/$f" -filter_complex \
         "[0]crop=$3[a];[1]crop=$3[b];[0][1]blend=all_expr='128+4*(B-A)',crop=$3[d];[a][b][d]hstack=3" "$4"
}
# d6's grimace (source frame ~252) onto the webcam clip's output frame 126 (detail.png: the face; detail_zoom.png:
# the chin, 3x).
detail_runs liveportrait_d6.mp4 130 d6
detail_difference d6 126 320:360:80:60 "$OUT/detail.png"
ffmpeg -loglevel error -y -i "$OUT/detail/d6_off/frame_000126.png" -i "$OUT/detail/d6_transient/frame_000126.png" -filter_complex \
       "[0]crop=120:90:150:250,scale=360:270:flags=neighbor[a];[1]crop=120:90:150:250,scale=360:270:flags=neighbor[b];[a][b]hstack" \
       "$OUT/detail_zoom.png"
# d14 onto the webcam clip, output frame 160: her jaw's edge over the shadowed neck lies inside her fitted face, a
# step the transfer must not read as a fold (it drew a thin curve down his left cheek until 2026-12-02)
# (detail_outline.png).
detail_runs liveportrait_d14.mp4 170 d14
detail_difference d14 160 200:220:130:120 "$OUT/detail_outline.png"
# A photo as the target (docs/reenactment.md, "A fitted light with a dark channel"): the Breaking Bad still, held
# for d6's 300 frames, graded teal and orange with a hard key light; output frames 120 and 252, and a crop of frame
# 120 beside the still and the pass-through (still_crop.png: still | pass-through | reenacted).
STILL="$ROOT/../shared/data/faces-68/breakingbad.jpg"
if [ -f "$STILL" ]; then
  mkdir -p "$OUT/still"
  "$FR" reenact --source "$VIDEOS/liveportrait_d6.mp4" --target "$STILL" --frames 300 --out "$OUT/still/reenact.mp4" \
        --quiet --sheets "$OUT/still" --sheet-frames 120,252 --frames-dir "$OUT/still/reenact"
  "$FR" reenact --source "$VIDEOS/liveportrait_d6.mp4" --target "$STILL" --frames 125 --mode pass-through \
        --out "$OUT/still/pass-through.mp4" --quiet --frames-dir "$OUT/still/pass-through"
  ffmpeg -loglevel error -y -i "$STILL" -i "$OUT/still/pass-through/frame_000120.png" -i "$OUT/still/reenact/frame_000120.png" \
         -filter_complex "[0]crop=260:320:600:120[a];[1]crop=260:320:600:120[b];[2]crop=260:320:600:120[c];[a][b][c]hstack=3" \
         "$OUT/still_crop.png"
fi
# Lids the output closes on a face that never blinks (issue #28, partly solved): d14 blinking (output frame 66) and
# with her eyes shut (150, 190) onto NASA's portrait (the demo's real face, from the scikit-image wheel `demo
# --fetch-only` keeps in the cache), target above output around the eyes at frame 150 (portrait_lids.png). Measured
# 2026-12-04: the closed lids are the skin's colour (208, 179, 154 against 208, 179, 159 between brow and lid) but
# flat, with no shading across the lid (the crease and the brows stay); the same with `--albedo-texture 0`. The
# dotted lash line is an unbroken one in her lashes' colour since that evening (docs/reenactment.md).
WHEEL="$(ls "${XDG_CACHE_HOME:-$HOME/.cache}"/face-reenact/scikit_image-0.22.0-*.whl 2>/dev/null | head -n 1)"
if [ -n "$WHEEL" ]; then
  mkdir -p "$OUT/portrait_lids"
  portrait="$OUT/portrait_lids/astronaut.png" eyes="crop=110:40:190:90,scale=440:160:flags=neighbor"
  python3 -c 'import sys, zipfile; open(sys.argv[2], "wb").write(zipfile.ZipFile(sys.argv[1]).read(sys.argv[3]))' \
          "$WHEEL" "$portrait" skimage/data/astronaut.png
  "$FR" reenact --source "$src" --target "$portrait" --frames 200 --out "$OUT/portrait_lids/reenact.mp4" \
        --quiet --sheets "$OUT/portrait_lids" --sheet-frames 66,150,190
  ffmpeg -loglevel error -y -i "$portrait" -i "$OUT/portrait_lids/reenact.mp4" -filter_complex \
         "[0]$eyes[a];[1]select='eq(n\,150)',$eyes[b];[a][b]vstack" -frames:v 1 "$OUT/portrait_lids.png"
  # Crossed eyes (docs/tracker.md, "Gaze", item 10): d6 crossing hers at 80 and 248, one eye turned in at 112, onto
  # the same portrait; the source's eyes above the output's, frames 80, 112, 248 (crossed_eyes.png; with FR_CLI set
  # to an earlier build, a before: the output's eyes looked ahead at 80 and 248).
  "$FR" reenact --source "$VIDEOS/liveportrait_d6.mp4" --target "$portrait" --frames 250 --quiet \
        --out "$OUT/portrait_lids/crossed.mp4" --frames-dir "$OUT/portrait_lids/crossed"
  ffmpeg -loglevel error -y -i "$VIDEOS/liveportrait_d6.mp4" -i "$OUT/portrait_lids/crossed/frame_000080.png" \
         -i "$OUT/portrait_lids/crossed/frame_000112.png" -i "$OUT/portrait_lids/crossed/frame_000248.png" \
         -filter_complex "[0]select='eq(n\,80)+eq(n\,248)+eq(n\,112)',crop=240:80:120:185,scale=440:147,tile=3x1[s];$(
           for k in 1 2 3; do printf '[%d]%s[o%d];' $k "$eyes" $k; done)[o1][o2][o3]hstack=3[o];[s][o]vstack" \
         -frames:v 1 "$OUT/crossed_eyes.png"
fi
# The virtual mirror (docs/reenactment.md, "Virtual mirror"): a round sticker (made here: magenta, transparent around it)
# on the left cheek, and the light from the image's left, on the webcam clip and on d14; frame 50 of each, input |
# sticker | light, side by side (mirror_webcam.png, mirror_d14.png).
mkdir -p "$OUT/mirror"
ffmpeg -loglevel error -y -f lavfi -i "color=c=black:s=64x64,format=rgba" -frames:v 1 \
       -vf "geq=r='255':g='0':b='200':a='if(lt(hypot(X-31.5,Y-31.5),30),255,0)'" "$OUT/mirror/sticker.png"
for pair in webcam:webcam_talking_640x480.wmv d14:liveportrait_d14.mp4; do
  name="${pair%%:*}" clip="${pair#*:}"
  "$FR" mirror --input "$VIDEOS/$clip" --frames 52 --texture "$OUT/mirror/sticker.png" --at left-cheek \
        --out "$OUT/mirror/${name}_sticker" --quiet
  "$FR" mirror --input "$VIDEOS/$clip" --frames 52 --light left --out "$OUT/mirror/${name}_left" --quiet
  ffmpeg -loglevel error -y -i "$OUT/mirror/${name}_sticker/frame_000050.png" -i "$OUT/mirror/${name}_left/frame_000050.png" \
         -ss 0 -i "$VIDEOS/$clip" -filter_complex "[2]select='eq(n\,50)'[in];[in][0][1]hstack=3" -frames:v 1 \
         "$OUT/mirror_${name}.png"
done
# The actor's albedo texture (docs/reenactment.md, "The actor's albedo texture"): a pass-through with the albedo-map
# appearance, the per-vertex albedo alone (--albedo-texture 0) against the texture, on the webcam clip (frame 30) and
# on d14 (frame 70; the source d0 ends those runs): input | per-vertex | texture, the face 2x (albedo_texture_*.png).
mkdir -p "$OUT/albedo_texture"
for pair in webcam:webcam_talking_640x480.wmv:30:240:280:200:120 d14:liveportrait_d14.mp4:70:260:300:126:120; do
  IFS=: read -r name clip frame cw ch cx cy <<< "$pair"
  source="$VIDEOS/$clip"
  [ "$name" = webcam ] || source="$VIDEOS/liveportrait_d0.mp4"
  for size in 0 2048; do
    "$FR" reenact --source "$source" --target "$VIDEOS/$clip" --frames $((frame + 1)) --mode pass-through \
          --appearance albedo-map --albedo-texture "$size" --out "$OUT/albedo_texture/${name}_$size.mp4" \
          --frames-dir "$OUT/albedo_texture/${name}_$size" --quiet
  done
  f="frame_$(printf %06d "$frame").png" crop="crop=$cw:$ch:$cx:$cy,scale=2*iw:-1"
  ffmpeg -loglevel error -y -ss 0 -i "$VIDEOS/$clip" -i "$OUT/albedo_texture/${name}_0/$f" -i "$OUT/albedo_texture/${name}_2048/$f" \
         -filter_complex "[0]select='eq(n\,$frame)',$crop[a];[1]$crop[b];[2]$crop[c];[a][b][c]hstack=3" -frames:v 1 \
         "$OUT/albedo_texture_$name.png"
done
echo "sheets in $OUT: *.overlay.png (fit over the clip), sheet_NNNNNN.png (source | target | output, the faces and the mouth), brows/ (raise, frown, after the light drifted), mouth_{auto,model}/ (the target's own mouth against the model's), mirror_*.png (input | sticker | light from the left), detail*.png (without | with the source's folds | difference; detail_outline.png: a jaw's edge that must not become a fold), still/ and still_crop.png (a photo as the target), portrait_lids/ and portrait_lids.png (lids closed on a face that never blinks), crossed_eyes.png (d6 crossing her eyes), lids.png and lids/ (closed lids), bared_teeth/ (a grimace onto a wide-open mouth filmed from below), closed_loop_*.json (the output tracked again), albedo_texture_*.png (input | per-vertex albedo | albedo texture)"
