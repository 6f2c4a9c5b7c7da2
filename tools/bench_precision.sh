#!/usr/bin/env bash
# The precision table: each benchmark run by nst3d --precision fp32, nst3d
# --precision bf16, the PyTorch peer in fp32 and the peer with --bf16
# (torch.autocast bfloat16), interleaved round by round in the same minutes,
# 2 threads each; prints every run, the medians and nst3d / best peer.
#
#   bash tools/bench_precision.sh [ROUNDS] [WHICH...]
#   WHICH: volume-velocity volume-density train-density train-velocity infer (default: all),
#          train-density-128 (a 128^3 patch; not in the default set, about 6 minutes)
#
# The run's lscpu flags say which bf16 unit the CPU has; without one the
# nst3d bf16 runs are the emulated path (and the peer's bf16 is oneDNN's).
set -euo pipefail
cd "$(dirname "$0")/.."
ROUNDS=${1:-3}
shift || true
WHICH=("$@")
[ ${#WHICH[@]} -gt 0 ] || WHICH=(volume-velocity volume-density train-density train-velocity infer)
. tools/bench_common.sh
echo "cpu bf16 units: $(grep -m1 -o -w -E 'amx_bf16|avx512_bf16' /proc/cpuinfo | sort -u | tr '\n' ' ' || true)(none listed = emulated)"
# The peer's time depends on its PyTorch build as much as on the CPU: both named with every run.
echo "cpu: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | xargs) (family $(grep -m1 'cpu family' /proc/cpuinfo | cut -d: -f2 | xargs), model $(grep -m1 '^model' /proc/cpuinfo | cut -d: -f2 | xargs)); $("$PY" -c 'import torch; print("torch", torch.__version__)' 2>/dev/null || echo 'torch missing')"
NST=./target/release/nst3d
run_nst() { # precision, bench args... -> last number
  "$NST" --threads 2 --precision "$1" bench "${@:2}" 2>/dev/null | tail -1 | awk '{print $2}'
}
for w in "${WHICH[@]}"; do
  case $w in
    volume-velocity) nargs=(volume-iter --n 128 --mode velocity); targs=(../shared/bench/torch_ref.py --n 128 --mode velocity) ;;
    volume-density) nargs=(volume-iter --n 128 --mode density); targs=(../shared/bench/torch_ref.py --n 128 --mode density) ;;
    train-density) nargs=(train-step --patch 64 --mode density); targs=(../shared/bench/torch_ff_ref.py --patch 64 --mode density) ;;
    train-density-128) nargs=(train-step --patch 128 --mode density); targs=(../shared/bench/torch_ff_ref.py --patch 128 --mode density) ;;
    train-velocity) nargs=(train-step --patch 64 --mode velocity); targs=(../shared/bench/torch_ff_ref.py --patch 64 --mode velocity) ;;
    infer) nargs=(infer --n 128); targs=(../shared/bench/torch_ff_ref.py --infer 128) ;;
    *) echo "unknown benchmark $w" >&2; exit 2 ;;
  esac
  a=(); b=(); c=(); d=()
  for r in $(seq "$ROUNDS"); do
    x=$(run_nst fp32 "${nargs[@]}")
    y=$(run_nst bf16 "${nargs[@]}")
    z=$("$PY" "${targs[@]}" --threads 2 2>/dev/null | tail -1 | awk '{print $2}')
    u=$("$PY" "${targs[@]}" --threads 2 --bf16 2>/dev/null | tail -1 | awk '{print $2}')
    echo "$w round $r: nst3d fp32 $x  nst3d bf16 $y  torch fp32 $z  torch bf16 $u (ms)"
    a+=("$x"); b+=("$y"); c+=("$z"); d+=("$u")
  done
  ma=$(med "${a[@]}"); mb=$(med "${b[@]}"); mc=$(med "${c[@]}"); md=$(med "${d[@]}")
  best_peer=$(printf '%s\n%s\n' "$mc" "$md" | sort -g | head -1)
  best_ours=$(printf '%s\n%s\n' "$ma" "$mb" | sort -g | head -1)
  echo "$w medians: nst3d fp32 $ma, bf16 $mb; torch fp32 $mc, bf16 $md; nst3d best / torch fp32 $(echo "scale=3; $best_ours / $mc" | bc), / torch bf16 $(echo "scale=3; $best_ours / $md" | bc), / best peer $(echo "scale=3; $best_ours / $best_peer" | bc)"
done
