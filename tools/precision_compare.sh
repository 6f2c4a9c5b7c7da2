#!/usr/bin/env bash
# Stylizes the shared smoke frame, a plume frame and the Bangs groom at
# their defaults with --precision fp32 and with --precision bf16 and prints
# each run's style-loss drop, their difference, and a side-by-side preview of
# the smoke (docs/guide/performance.md). On a CPU without a bf16 unit the
# bf16 runs are emulated (same roundings, fp32 speed or slower).
#
#   bash tools/precision_compare.sh [OUT_DIR]      (default: out/precision)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/precision}
mkdir -p "$OUT"
cargo build --release -q -p nst3d-cli
NST=./target/release/nst3d
D=../shared/data
STYLE=$D/styles/starry_night.jpg
drop() { sed -n 's/.*(\([0-9.-]*\)% lower).*/\1/p' "$1" | tail -1; }
for p in fp32 bf16; do
  /usr/bin/time -f "%e s" $NST --precision "$p" volume --input $D/volumes/smoke_000003.vdb --style $STYLE \
    --out "$OUT/smoke_$p.vdb" > "$OUT/smoke_$p.txt" 2> "$OUT/smoke_$p.err"
  /usr/bin/time -f "%e s" $NST --precision "$p" volume --input $D/volumes/plume48/fluid_data_0030.vdb --style $STYLE \
    --out "$OUT/plume_$p.vdb" > "$OUT/plume_$p.txt" 2> "$OUT/plume_$p.err"
  /usr/bin/time -f "%e s" $NST --precision "$p" strands --groom $D/grooms/Bangs_100.hair --mesh $D/grooms/Bangs_head.ply \
    --style $STYLE --out "$OUT/bangs_$p.ply" > "$OUT/bangs_$p.txt" 2> "$OUT/bangs_$p.err"
done
for job in smoke plume bangs; do
  echo "== $job"
  for p in fp32 bf16; do echo "$p: $(tail -1 "$OUT/${job}_$p.txt")  [$(grep -E '^[0-9.]+ s$' "$OUT/${job}_$p.err" | tail -1)]"; done
done
$NST preview --input "$OUT/smoke_fp32.vdb" --compare "$OUT/smoke_bf16.vdb" --out "$OUT/smoke_fp32_vs_bf16.png"
echo "preview: $OUT/smoke_fp32_vs_bf16.png"
