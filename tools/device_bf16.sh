#!/usr/bin/env bash
# The bf16 measurements on a machine that has a bf16 unit but no Rust
# toolchain (a lent machine with no network): runs binaries built elsewhere.
#
#   bash tools/device_bf16.sh pack            # here: fills devbin/ (git-ignored)
#   bash tools/device_bf16.sh run [ROUNDS]    # there: tests, then benchmarks
#   bash tools/device_bf16.sh quick           # there: unit tests, VGG-19, volume-iter
#                                             # and the network's auto path, ~3 min
#
# `run` prints the CPU's bf16 flags, runs the bf16/precision tests of core,
# features, loss and network on the dispatched path (AMX or AVX512-BF16 where
# present, with each hardware kernel's self-check against the scalar one),
# then the precision benchmarks, 2 threads pinned to cores 0-1, nst3d fp32 /
# nst3d auto / PyTorch fp32 / PyTorch bf16 interleaved round by round. Output
# goes to stdout and to $OUT/bf16.log when $OUT is set.
set -uo pipefail
cd "$(dirname "$0")/.."
D=devbin
case "${1:-}" in
pack)
  set -e
  cargo build --release -q -p nst3d-cli
  rm -rf "$D" && mkdir -p "$D/bench"
  cp target/release/nst3d "$D/"
  for b in vgg nnst; do
    f=$(ls -t target/release/deps/$b-* | grep -v '\.d$' | head -1)
    cp "$f" "$D/bench-$b"
  done
  cargo test --release --no-run -p nst3d-core -p nst3d-features -p nst3d-loss -p nst3d-network 2>&1 |
    grep -o 'target/release/deps/[^)]*' | while read -r f; do cp "$f" "$D/test-$(basename "$f")"; done
  strip "$D"/nst3d "$D"/bench-* "$D"/test-*
  cp ../shared/bench/*.py "$D/bench/"
  cp tools/bench/*.py "$D/bench/"
  grep -qx "/$D/" .git/info/exclude || echo "/$D/" >>.git/info/exclude
  du -sh "$D"
  ;;
run | quick)
  MODE=$1
  ROUNDS=${2:-1}
  LOG=${OUT:-/tmp}/bf16.log
  mkdir -p "$(dirname "$LOG")"
  exec > >(tee -a "$LOG") 2>&1
  PY=${PY:-python3}
  pin() { taskset -c 0,1 "$@"; }
  echo "== cpu"
  grep -m1 'model name' /proc/cpuinfo
  echo "bf16 flags: $(grep -m1 -o -w -E 'amx_bf16|amx_tile|avx512_bf16' /proc/cpuinfo | sort -u | tr '\n' ' ')"
  nproc
  echo "== dispatched path"
  pin "$D/nst3d" --threads 2 bench volume-iter --n 16 --iters 1 2>&1 | grep -i precision
  echo "== unit tests of core, features, loss, network on the dispatched path (then forced fp32)"
  for t in "$D"/test-nst3d_*; do
    for p in auto fp32; do
      echo "-- $(basename "$t") NST3D_PRECISION=$p"
      NST3D_PRECISION=$p timeout 300 "$t" --test-threads 8 2>&1 | grep -E 'test result|panicked|FAILED|^    [a-z_:]+$'
    done
  done
  if ! grep -q -w -E 'amx_bf16|avx512_bf16' /proc/cpuinfo; then
    echo "no bf16 unit on this CPU: nothing to measure"
    exit 0
  fi
  nst() { pin "$D/nst3d" --threads 2 --precision "$1" bench "${@:2}" 2>/dev/null | tail -1 | awk '{print $2}'; }
  tor() { pin "$PY" "$@" --threads 2 2>/dev/null | tail -1 | awk '{print $2}'; }
  echo "== VGG-19 to relu4_1, 3x256x256, forward + backward (2 threads)"
  for p in fp32 auto; do echo "nst3d $p: $(NST3D_PRECISION=$p pin "$D/bench-vgg" 256 5 2>&1 | tail -1)"; done
  pin "$PY" "$D/bench/vgg_torch.py" --runs 5 2>&1 | tail -2
  pin "$PY" "$D/bench/vgg_torch.py" --runs 5 --bf16 2>&1 | tail -2
  if [ "$MODE" = quick ]; then
    for r in 1 2; do
      for w in velocity density; do
        echo "volume-$w round $r: nst3d fp32 $(nst fp32 volume-iter --n 128 --mode $w)  nst3d auto $(nst auto volume-iter --n 128 --mode $w)  torch bf16 $(tor "$D/bench/torch_ref.py" --n 128 --mode $w --bf16) (ms)"
      done
    done
    echo "train-density: nst3d fp32 $(nst fp32 train-step --patch 64 --mode density)  nst3d auto $(nst auto train-step --patch 64 --mode density) (ms)"
    pin "$D/nst3d" --threads 2 bench train-step --patch 64 --iters 1 2>&1 | grep -i precision
    echo "infer: nst3d fp32 $(nst fp32 infer --n 128)  nst3d auto $(nst auto infer --n 128) (ms)"
    exit 0
  fi
  echo "== NNST matching (cargo bench nnst shape)"
  for p in fp32 auto; do echo "nst3d $p: $(NST3D_PRECISION=$p pin "$D/bench-nnst" 2>&1 | tail -1)"; done
  echo "torch fp32: $(pin "$PY" "$D/bench/nnst_match_torch.py" 2>&1 | tail -1)"
  echo "torch bf16: $(pin "$PY" "$D/bench/nnst_match_torch.py" --bf16 2>&1 | tail -1)"
  for w in volume-velocity volume-density train-density train-velocity infer; do
    case $w in
      volume-velocity) n=(volume-iter --n 128 --mode velocity); t=("$D/bench/torch_ref.py" --n 128 --mode velocity) ;;
      volume-density) n=(volume-iter --n 128 --mode density); t=("$D/bench/torch_ref.py" --n 128 --mode density) ;;
      train-density) n=(train-step --patch 64 --mode density); t=("$D/bench/torch_ff_ref.py" --patch 64 --mode density) ;;
      train-velocity) n=(train-step --patch 64 --mode velocity); t=("$D/bench/torch_ff_ref.py" --patch 64 --mode velocity) ;;
      infer) n=(infer --n 128); t=("$D/bench/torch_ff_ref.py" --infer 128) ;;
    esac
    for r in $(seq "$ROUNDS"); do
      echo "$w round $r: nst3d fp32 $(nst fp32 "${n[@]}")  nst3d auto $(nst auto "${n[@]}")  torch fp32 $(tor "${t[@]}")  torch bf16 $(tor "${t[@]}" --bf16) (ms)"
    done
  done
  ;;
*)
  echo "usage: tools/device_bf16.sh pack | run [ROUNDS]" >&2
  exit 2
  ;;
esac
