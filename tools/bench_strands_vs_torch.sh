#!/usr/bin/env bash
# Measures `nst3d bench strands-iter` against its PyTorch peer
# (tools/bench/strands_iter_torch.py) in alternating runs, same minutes, same
# machine: one iteration of strand stylization on the Bangs groom at SIZE²
# (transport, constraints, splat render, VGG-19, NNST loss, backward, AdamW).
# Prints each pair (wall ms and CPU ms per iteration), the medians, the
# ratios and peak memory. The machine is shared: CPU time (user + sys over
# the timed iterations) is disturbed less by neighbours than wall time.
#
#   bash tools/bench_strands_vs_torch.sh [SIZE] [ROUNDS] [ITERS] [nst3d bench strands-iter args...]
#   (defaults: 600, 3, 3, the Bangs groom; e.g. `... 600 3 2 --groom G --mesh M` for another groom)
#
# The first nst3d run writes the scene, camera and matched targets to
# $DUMP (default /tmp/nst3d_strands_dump) and the peer reads them, so both
# do the same work on the same inputs. Needs a Python with torch:
# $TORCH_PYTHON, else ./.venv-torch (created with `pip install torch numpy`).
set -euo pipefail
cd "$(dirname "$0")/.."
SIZE=${1:-600}
ROUNDS=${2:-3}
ITERS=${3:-3}
EXTRA=("${@:4}")
DUMP=${DUMP:-/tmp/nst3d_strands_dump}
. tools/bench_common.sh
log=$(mktemp -d)
ours=(); theirs=(); ours_cpu=(); theirs_cpu=()
for r in $(seq "$ROUNDS"); do
  dump=(); [ "$r" = 1 ] && dump=(--dump "$DUMP")
  /usr/bin/time -v ./target/release/nst3d --threads 2 bench strands-iter --size "$SIZE" --iters "$ITERS" "${dump[@]}" "${EXTRA[@]}" \
    >"$log/nst3d.$r" 2>"$log/nst3d_time.$r"
  /usr/bin/time -v "$PY" tools/bench/strands_iter_torch.py "$DUMP" --threads 2 --iters "$ITERS" \
    >"$log/torch.$r" 2>"$log/torch_time.$r"
  o=$(field ms_per_iter "$log/nst3d.$r"); t=$(field torch_ms_per_iter "$log/torch.$r")
  oc=$(field cpu_ms_per_iter "$log/nst3d.$r"); tc=$(field cpu_ms_per_iter "$log/torch.$r")
  echo "round $r ($(date -u +%H:%M:%S) UTC): nst3d ${o} ms (cpu ${oc})  torch ${t} ms (cpu ${tc})  ratio $(echo "scale=3; $o / $t" | bc)  cpu ratio $(echo "scale=3; $oc / $tc" | bc)"
  ours+=("$o"); theirs+=("$t"); ours_cpu+=("$oc"); theirs_cpu+=("$tc")
done
echo "--- nst3d, last round:"; cat "$log/nst3d.$ROUNDS"
echo "--- torch, last round:"; grep -v '^$' "$log/torch.$ROUNDS"
mo=$(med "${ours[@]}"); mt=$(med "${theirs[@]}"); mc=$(med "${ours_cpu[@]}"); tcm=$(med "${theirs_cpu[@]}")
echo "strands-iter ${SIZE}x${SIZE}: median nst3d ${mo} ms, torch ${mt} ms, ratio $(echo "scale=3; $mo / $mt" | bc);" \
  "cpu nst3d ${mc} ms, torch ${tcm} ms, ratio $(echo "scale=3; $mc / $tcm" | bc);" \
  "peak RSS nst3d $(peak "$log/nst3d_time.$ROUNDS") MB, torch $(peak "$log/torch_time.$ROUNDS") MB"
rm -rf "$log"
