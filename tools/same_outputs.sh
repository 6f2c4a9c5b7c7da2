#!/usr/bin/env bash
# Runs every nst3d pipeline on the shared examples with one binary and prints
# the sha256 of each file it writes, so two builds can be compared byte for
# byte (the library-first refactor promised no behaviour change):
#
#   bash tools/same_outputs.sh BINARY OUTDIR > hashes.txt
#   diff before.txt after.txt      # empty: the outputs are byte-identical
#
# Settings are cut down from the defaults (fewer iterations, smaller renders)
# so one pass takes a few minutes on two cores; every code path of the jobs
# still runs: single frames in both modes, a chunked sequence with warm-up and
# an empty frame, a groom, an animated groom with EMA + 1-euro, the fur-ball
# generator and the preview sheets. Threads are pinned: results are
# bit-identical on the same thread count only.
set -euo pipefail
BIN=$(realpath "$1"); OUT=$2
DATA=$(realpath "$(dirname "$0")/../../shared/data")
rm -rf "$OUT"; mkdir -p "$OUT"; cd "$OUT"
N="$BIN --threads 2"
STYLE=$DATA/styles/starry_night.jpg
run() { "$@" >> stdout.txt 2>> log.txt || { echo "FAILED: $*" >&2; tail -3 log.txt >&2; exit 1; }; }

for mode in density velocity; do
  run $N volume --input "$DATA/volumes/smoke_000003.vdb" --style "$STYLE" --mode $mode \
      --octaves 2 --iters 4 --eval-cameras omniview:3 --out "smoke3_$mode.vdb" --preview "smoke3_$mode.png"
done
# A chunked sequence with warm-up: frames 1-3 of the OpenUSD smoke (frame 1 is empty, no velocity grid).
run $N volume --input "$DATA/volumes/smoke_00000#.vdb" --frames 1-3 --style "$STYLE" --iters 2 --octaves 2 \
    --out 'usd_####.vdb'
# plume48 with its staggered velocity grid, in two chunks.
for chunk in 20-21 22-23; do
  run $N volume --input "$DATA/volumes/plume48/fluid_data_####.vdb" --frames 20-23 --chunk $chunk --warmup 1 \
      --style "$STYLE" --iters 2 --octaves 2 --cameras omniview:2 --out 'plume_####.vdb'
done
run $N preview --input "$DATA/volumes/smoke_000003.vdb" --compare smoke3_velocity.vdb --out sheet.png
run $N preview --input "$DATA/volumes/smoke_000003.vdb" --turntable 3 --out 'turn_##.png'
run $N preview --input 'plume_####.vdb' --frames 20-23 --out 'pprev_####.png'

run $N strands --groom "$DATA/grooms/Bangs_100.hair" --mesh "$DATA/grooms/Bangs_head.ply" --style "$STYLE" \
    --scale-iters 2,2,2 --render-size 96 --out bangs.usda --preview bangs.png
run $N strands --groom "$DATA/grooms/Bangs_100_binary.ply" --mesh "$DATA/grooms/Bangs_head.ply" --style "$STYLE" \
    --scale-iters 0,0,2 --render-size 96 --out bangs.ply
run $N strands generate fur-ball --strands 300 --frames 1-3 --out 'fur_####.ply' --mesh-out sphere.ply
run $N strands --groom 'fur_####.ply' --frames 1-3 --mesh sphere.ply --style "$STYLE" --preset fur-ball \
    --scale-iters 1,1,2 --render-size 96 --out 'sfur_####.usda' --preview 'sfur_####.png'
run $N strands generate grass --strands 50 --out grass.usda

# The reports (stdout) and notes (log.txt, less the progress lines) are compared too.
grep -v '^\[' log.txt > notes.txt
find . -type f ! -name log.txt ! -path '*/.nst3d-work/*' | sort | xargs sha256sum
