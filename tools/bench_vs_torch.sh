#!/usr/bin/env bash
# Measures `nst3d bench volume-iter` against the PyTorch peer
# (../shared/bench/torch_ref.py) in alternating runs, same minute, same
# machine, and prints each pair, the medians and the ratio, plus peak memory.
#
#   bash tools/bench_vs_torch.sh [N] [ROUNDS]        (defaults: 128, 3)
#
# Needs a Python with torch: $TORCH_PYTHON, else ./.venv-torch (created with
# `pip install torch numpy` on first use).
set -euo pipefail
cd "$(dirname "$0")/.."
N=${1:-128}
ROUNDS=${2:-3}
. tools/bench_common.sh
for mode in velocity density; do
  ours=(); theirs=(); ours_mb=0; theirs_mb=0
  for r in $(seq "$ROUNDS"); do
    o=$( { /usr/bin/time -v ./target/release/nst3d --threads 2 bench volume-iter --n "$N" --mode "$mode" 2>/tmp/nst3d_time.txt; } | tail -1 | awk '{print $2}')
    ours_mb=$(peak /tmp/nst3d_time.txt)
    t=$( { /usr/bin/time -v "$PY" ../shared/bench/torch_ref.py --n "$N" --mode "$mode" --threads 2 2>/tmp/torch_time.txt; } | tail -1 | awk '{print $2}')
    theirs_mb=$(peak /tmp/torch_time.txt)
    echo "$mode round $r: nst3d ${o} ms  torch ${t} ms  ratio $(echo "scale=3; $o / $t" | bc)"
    ours+=("$o"); theirs+=("$t")
  done
  mo=$(med "${ours[@]}")
  mt=$(med "${theirs[@]}")
  echo "$mode N=$N: median nst3d ${mo} ms, torch ${mt} ms, ratio $(echo "scale=3; $mo / $mt" | bc); peak RSS nst3d ${ours_mb} MB, torch ${theirs_mb} MB"
done
