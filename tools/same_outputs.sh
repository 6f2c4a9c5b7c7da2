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
# an empty frame, the colour stage of a volume frame and of a groom, the
# feed-forward network (inference on a frame and a sequence, a few training
# steps and their resume), a groom, an animated groom with EMA + 1-euro, the
# fur-ball generator and the preview sheets. Threads are pinned: results are
# bit-identical on the same thread count only. The training checkpoint holds
# the run's clock and is left out; the reports' minutes and
# throughputs are blanked.
set -euo pipefail
BIN=$(realpath "$1"); OUT=$2
ROOT=$(realpath "$(dirname "$0")/..")
DATA=$(realpath "$ROOT/../shared/data")
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
# The colour stage of a single frame (16 cameras, joint density scale).
run $N volume --input "$DATA/volumes/smoke_000003.vdb" --style "$DATA/styles/woman_with_hat.jpg" --mode density \
    --octaves 1 --iters 2 --color --out smoke3_color.vdb
# The feed-forward network: the example model on a frame (tiled) and on a sequence.
MODEL=$ROOT/models/starry_density.safetensors
run $N volume --input "$DATA/volumes/smoke_000003.vdb" --model "$MODEL" --tile 32 --tile-margin 8 \
    --out ff_smoke3.vdb --preview ff_smoke3.png
run $N volume --input "$DATA/volumes/plume48/fluid_data_####.vdb" --frames 20-21 --model "$MODEL" --out 'ffplume_####.vdb'
# A few training steps of a small network, then the same command again: it resumes from the checkpoint.
for pass in 1 2; do
  run $N train --input "$DATA/volumes/smoke_00000#.vdb" --frames 2-3 --style "$STYLE" --out tiny.safetensors \
      --channels 4 --patch 16 --steps 3 --checkpoint-every 2 --octaves 1
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
run $N strands --groom "$DATA/grooms/Bangs_100.hair" --mesh "$DATA/grooms/Bangs_head.ply" --style "$DATA/styles/woman_with_hat.jpg" \
    --scale-iters 0,0,1 --render-size 64 --color --out bangs_color.ply
run $N strands generate grass --strands 50 --out grass.usda

# The reports (stdout) and notes (log.txt, less the progress lines) are compared too.
grep -v '^\[' log.txt > notes.txt
sed -i -e 's/ in [0-9.]* min;/ in _ min;/' -e 's/([0-9.]* Mvoxels\/s/(_ Mvoxels\/s/' stdout.txt
find . -type f ! -name log.txt ! -name '*.ckpt' ! -path '*/.nst3d-work/*' | sort | xargs sha256sum
