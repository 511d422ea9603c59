#!/usr/bin/env bash
# Seams of a long shot fitted as windows: a synth clip of F frames (default 600 at 320×180,
# scene rack) through `batch run` as windows of W frames overlapping by O, all windows at once
# (as `batch submit` runs them), each fitted for M minutes (or ITERS=N steps); then the stitched sharp export scored against
# the truth: per-frame PSNR and tPSNR in the overlaps (the seams) against the windows'
# interiors, and the input's for reference. Needs python3 with numpy and OpenCV (python3-opencv).
#   tools/slurm/bench_windows.sh [DIR=/tmp/refocus_bench_windows] [F=600] [W=240] [O=16] [M=2]
set -euo pipefail
here=$(cd "$(dirname "$0")/../.." && pwd)
bin=$here/build/refocus
dir=${1:-/tmp/refocus_bench_windows}; F=${2:-600}; W=${3:-240}; O=${4:-16}; M=${5:-2}
scene=${SCENE:-rack}
budget="\"minutes\": $M"; [ -n "${ITERS:-}" ] && budget="\"iters\": $ITERS"
mkdir -p "$dir"; cd "$dir"
[ -f clip/sharp_0000.png ] || "$bin" synth --scene "$scene" -o clip --size 320x180 --frames "$F" >/dev/null 2>&1
cat >shots.json <<JSON
{"shots": [{"name": "long", "clip": "clip/input_%04d.png", "project": "p/long", $budget,
            "window": $W, "overlap": $O, "exports": [{"what": "sharp", "out": "out/long"}]}]}
JSON
n=$("$bin" batch plan shots.json | grep -c ' new ')
# The windows at once: a list of one shot runs its windows one after the other, so run the
# windows' own steps as tasks (what `batch submit` does), then the stitching export.
t0=$(date +%s)
"$bin" batch plan shots.json >/dev/null
for k in $(seq 0 $((n - 1))); do
  REFOCUS_THREADS=1 "$bin" batch shot shots.json --index 0 --window "$k" --threads 1 >"win$k.log" 2>&1 &
done
wait
t_fit=$(( $(date +%s) - t0 ))
"$bin" batch run shots.json >stitch.log
t_all=$(( $(date +%s) - t0 ))
echo "frames $F, windows $n of ≤$W overlapping by $O, fitted at once ($budget each): $t_fit s; with the stitched export $t_all s"
/usr/bin/python3 - "$dir" <<'PY'
import json, sys, cv2, numpy as np
d = sys.argv[1]
w = json.load(open(f"{d}/p/long/windows.json"))
F = w["frames"]
def rd(p): return cv2.imread(p).astype(np.float64)
def psnr(a, b): return 10 * np.log10(255.0**2 / max(np.mean((a - b) ** 2), 1e-12))
gt = [rd(f"{d}/clip/sharp_{t:04d}.png") for t in range(F)]
out = [rd(f"{d}/out/long/sharp_{t:04d}.png") for t in range(F)]
inp = [rd(f"{d}/clip/input_{t:04d}.png") for t in range(F)]
seam = set()
for a, b in zip(w["windows"], w["windows"][1:]):
    seam.update(range(b["first"], a["last"] + 1))
p = np.array([psnr(out[t], gt[t]) for t in range(F)])
pi = np.array([psnr(inp[t], gt[t]) for t in range(F)])
tp = np.array([psnr(out[t + 1] - out[t], gt[t + 1] - gt[t]) for t in range(F - 1)])
S = sorted(seam); I = [t for t in range(F) if t not in seam]
TS = [t for t in range(F - 1) if t in seam or t + 1 in seam]; TI = [t for t in range(F - 1) if t not in TS]
print(f"PSNR: seams {p[S].mean():.2f} dB (input {pi[S].mean():.2f}), interiors {p[I].mean():.2f} dB (input {pi[I].mean():.2f}): seams - interiors {p[S].mean() - p[I].mean():+.2f} dB")
print(f"gain over input: seams {(p[S] - pi[S]).mean():+.2f} dB, interiors {(p[I] - pi[I]).mean():+.2f} dB")
print(f"tPSNR: across seams {tp[TS].mean():.2f} dB, within windows {tp[TI].mean():.2f} dB")
PY
