#!/usr/bin/env bash
# The identity clip: real footage already in focus (OpenCV's vtest.avi, people walking past a
# static camera, from the Debian package opencv-doc), 30 frames at 384x288 as PNG, laid out as a
# one-clip corpus whose ground truth is the input itself, so that `refocus bench corpus` scores
# how close the fit's output comes back to the shot (docs/benchmarks.md, Identity).
#   tools/corpus/identity_clip.sh <out-dir>
set -euo pipefail
out=${1:?usage: identity_clip.sh <out-dir>}
clip="$out/identity_vtest"
mkdir -p "$clip"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$work" && apt-get download opencv-doc > /dev/null)
dpkg -x "$work"/opencv-doc_*.deb "$work/x"
avi=$(find "$work/x" -name vtest.avi | head -n 1)
[ -n "$avi" ] || { echo "identity_clip.sh: opencv-doc has no vtest.avi" >&2; exit 1; }
ffmpeg -loglevel error -y -i "$avi" -vf scale=384:288 -frames:v 30 -start_number 0 \
    "$clip/input_%04d.png"
for f in "$clip"/input_*.png; do cp "$f" "${f/input_/sharp_}"; done
cat > "$clip/clip.json" <<JSON
{"version": 1, "name": "identity_vtest", "split": "val", "source": "opencv-doc vtest.avi",
 "width": 384, "height": 288, "frames": 30, "fps": 10,
 "description": "real footage in focus: the output must come back as the input"}
JSON
echo "$clip"
