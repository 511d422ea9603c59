#!/usr/bin/env bash
# `export --what flow` against the synth clips' true flow: for each scene, a 160×90×8 clip, a
# fit of 60 steps with the true radius, the flow exported, and the end-point error's median and
# 90th percentile (px), over the background and the subject. Needs python3 with numpy and
# OpenCV (python3-opencv) to read the EXRs.
#   tools/bench_flow.sh [DIR=/tmp/refocus_bench_flow] [scenes: rack pillar pan tripod]
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
bin=$here/build/refocus
dir=${1:-/tmp/refocus_bench_flow}; shift || true
scenes=("$@"); [ ${#scenes[@]} -gt 0 ] || scenes=(rack pillar pan tripod)
rm -rf "$dir"; mkdir -p "$dir"; cd "$dir"
for sc in "${scenes[@]}"; do
  "$bin" synth --scene "$sc" -o "$sc" --size 160x90 --frames 8 >/dev/null 2>&1
  "$bin" new "$sc/input_%04d.png" -o "p_$sc" >/dev/null 2>&1
  "$bin" fit "p_$sc" --iters 60 --coc "$sc/coc_%04d.exr" >/dev/null 2>&1
  "$bin" export "p_$sc" --what flow --out "f_$sc" >/dev/null 2>&1
done
OPENCV_IO_ENABLE_OPENEXR=1 /usr/bin/python3 - "$dir" "${scenes[@]}" <<'PY'
import sys, cv2, numpy as np
d = sys.argv[1]
for sc in sys.argv[2:]:
    e, ebg, efg = [], [], []
    for t in range(7):
        g = cv2.imread(f"{d}/f_{sc}/flow_{t:04d}.exr", cv2.IMREAD_UNCHANGED)   # B, G, R = 0, dy, dx
        w = cv2.imread(f"{d}/{sc}/flow_{t:04d}.exr", cv2.IMREAD_UNCHANGED)
        a = cv2.imread(f"{d}/{sc}/alpha_{t:04d}.png", 0) / 255.0
        err = np.hypot(g[..., 2] - w[..., 2], g[..., 1] - w[..., 1])
        e.append(err.ravel()); ebg.append(err[a < 0.5]); efg.append(err[a >= 0.5])
    e, ebg, efg = (np.concatenate(x) for x in (e, ebg, efg))
    fg = f"{np.median(efg):.3f}" if efg.size else "-"
    print(f"{sc}: median EPE {np.median(e):.3f} px (background {np.median(ebg):.3f}, subject {fg}), p90 {np.percentile(e, 90):.3f}")
PY
