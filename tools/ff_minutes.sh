#!/usr/bin/env bash
# The "--minutes" check: `nst3d train --minutes M` with no other
# budget (the schedule sized to fill M minutes) against the 2,000-step
# default, same painting, frames, seed and thread count; both judged by
# tools/ff_judge.sh on frames neither saw.
#
#   bash tools/ff_minutes.sh OUTDIR [MINUTES] [THREADS]
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=$1; MIN=${2:-30}; TH=${3:-2}
BIN=./target/release/nst3d
STYLE=../shared/data/styles/starry_night.jpg
IN='../shared/data/volumes/plume48/fluid_data_####.vdb'
mkdir -p "$OUT"
train() { # name, extra args...
  local t0=$(date +%s)
  "$BIN" --threads "$TH" train --input "$IN" --frames 1-40 --style "$STYLE" --out "$OUT/$1.safetensors" "${@:2}" \
    > "$OUT/$1.log" 2>&1
  echo "$1: $(( $(date +%s) - t0 )) s wall; $(grep -E 'sized to|^trained' "$OUT/$1.log" | tr '\n' ' ')"
}
train minutes --minutes "$MIN"
train default
for f in ../shared/data/volumes/smoke_00000[23].vdb; do  # smoke_000001 is empty
  n=$(basename "$f" .vdb)
  for m in minutes default; do
    "$BIN" volume --model "$OUT/$m.safetensors" --input "$f" --out "$OUT/${n}_$m.vdb" > /dev/null
  done
  bash tools/ff_judge.sh "$STYLE" "$f" "$OUT/${n}_minutes.vdb" "$OUT/${n}_default.vdb"
done
