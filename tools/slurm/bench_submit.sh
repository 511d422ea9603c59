#!/usr/bin/env bash
# Slurm's cost per shot: N tiny synth shots (64×36×6, 30 steps, a PNG export) run by
# `batch run --jobs <cores>` (one thread a shot), then the same list through `batch submit
# --cpus 1` on a one-machine cluster (tools/slurm/local_cluster.sh). Prints both wall times, the
# overhead per shot in core-seconds, and whether every output is the same bytes.
#   tools/slurm/bench_submit.sh [SHOTS=20] [DIR=/tmp/refocus_bench_submit]   (root; build/refocus)
set -euo pipefail
here=$(cd "$(dirname "$0")/../.." && pwd)
bin=$here/build/refocus
n=${1:-20}; dir=${2:-/tmp/refocus_bench_submit}
cores=$(nproc)
rm -rf "$dir"; mkdir -p "$dir"; cd "$dir"
scenes=(rack tripod pan hunt walkout)
for s in "${scenes[@]}"; do "$bin" synth --scene "$s" -o "$s" --size 64x36 --frames 6 >/dev/null 2>&1; done
list() {  # $1: project and output prefix
  echo '{"shots": ['
  for i in $(seq 0 $((n - 1))); do
    s=${scenes[$((i % ${#scenes[@]}))]}
    printf '  {"name": "s%03d", "clip": "%s/input_%%04d.png", "project": "%s/p%03d", "iters": 30, "exports": [{"what": "sharp", "out": "%s_out/s%03d"}]}%s\n' \
      "$i" "$s" "$1" "$i" "$1" "$i" "$([ "$i" -lt $((n - 1)) ] && echo ,)"
  done
  echo ']}'
}
list here >here.json
list slurm >slurm.json

t0=$(date +%s.%N)
"$bin" batch run here.json --jobs "$cores" >run.log
t_run=$(echo "$(date +%s.%N) - $t0" | bc)

eval "$(bash "$here/tools/slurm/local_cluster.sh" start "$dir/cluster")"
trap 'bash "$here/tools/slurm/local_cluster.sh" stop "$dir/cluster"' EXIT
t0=$(date +%s.%N)
"$bin" batch submit slurm.json --cpus 1 >submit.log
job=$(python3 -c "import json;print(json.load(open('batch_slurm/slurm.json'))['job'])")
while squeue -h -r -j "$job" 2>/dev/null | grep -q .; do sleep 0.2; done
t_slurm=$(echo "$(date +%s.%N) - $t0" | bc)

same=0
for i in $(seq 0 $((n - 1))); do
  d=$(printf s%03d "$i")
  cmp -s <(cat here_out/$d/*.png) <(cat slurm_out/$d/*.png) && same=$((same + 1))
done
done_n=$("$bin" batch status slurm.json | grep -c ' done ')
printf 'shots %d on %d cores: batch run %.1f s, batch submit %.1f s (submit to last task done)\n' "$n" "$cores" "$t_run" "$t_slurm"
# The shots' own time (each task's "done in X s") against the slots Slurm held.
busy=$(cat batch_logs/slurm_"$job"_*.log | awk '/\] (done|skipped) in/ {s += $4} END {print s}')
printf 'overhead per shot: %.2f core-seconds against batch run; slots idle between tasks %.2f s a shot\n' \
  "$(echo "($t_slurm - $t_run) * $cores / $n" | bc -l)" "$(echo "($t_slurm * $cores - $busy) / $n" | bc -l)"
printf 'done %d/%d; outputs the same bytes: %d/%d\n' "$done_n" "$n" "$same" "$n"
