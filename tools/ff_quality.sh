#!/usr/bin/env bash
# The feed-forward quality study of docs/design/feedforward.md: one trained model
# against single-camera and omniview:16 optimisation on frames the
# model never saw, all scored by one judge — the mean Gram style loss from
# the 8 cameras of `ring:8:30` (none of them a training or optimisation
# view), measured on the written files by `nst3d volume --eval-cameras`
# (its "before" number is the loss of the file it reads) — plus the wall
# time of each stylization and turntable pictures.
#
#   bash tools/ff_quality.sh MODEL.safetensors MODE OUTDIR FRAME.vdb [FRAME.vdb ...]
#
# MODE (density or velocity) is the model's; the optimisations run in it too.
#
# Prints one table row per frame and method; pictures land in OUTDIR.
set -euo pipefail
cd "$(dirname "$0")/.."
MODEL=$1; MODE=$2; OUT=$3; shift 3
STYLE=../shared/data/styles/starry_night.jpg
BIN=./target/release/nst3d
EVAL=ring:8:30
mkdir -p "$OUT"

# Mean style loss of a file from the $EVAL cameras.
judge() {
  "$BIN" volume --input "$1" --style "$STYLE" --mode "$MODE" --upsample 1 --iters 1 --octaves 1 \
    --eval-cameras "$EVAL" --out "$OUT/judge_tmp.vdb" | sed -n 's/^held-out cameras .*: mean style loss \([^ ]*\) .*/\1/p'
}
ratio() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.3f", a / b }'; }
# Wall seconds of a command.
timed() {
  local t0 t1
  t0=$(date +%s.%N); "$@" > "$OUT/last.log"; t1=$(date +%s.%N)
  awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.2f", b - a }'
}

echo "| frame | method | style loss from $EVAL | vs input | wall s |"
echo "|---|---|---|---|---|"
for f in "$@"; do
  name=$(basename "$f" .vdb)
  base=$(judge "$f")
  echo "| $name | input | $base | 1 | |"
  t=$(timed "$BIN" volume --model "$MODEL" --input "$f" --out "$OUT/${name}_ff.vdb")
  l=$(judge "$OUT/${name}_ff.vdb"); echo "| $name | feed-forward | $l | $(ratio "$l" "$base") | $t |"
  t=$(timed "$BIN" volume --input "$f" --style "$STYLE" --mode "$MODE" --upsample 1 --out "$OUT/${name}_opt.vdb")
  l=$(judge "$OUT/${name}_opt.vdb"); echo "| $name | optimisation, front camera | $l | $(ratio "$l" "$base") | $t |"
  t=$(timed "$BIN" volume --input "$f" --style "$STYLE" --mode "$MODE" --upsample 1 --cameras omniview:16 --out "$OUT/${name}_omni.vdb")
  l=$(judge "$OUT/${name}_omni.vdb"); echo "| $name | optimisation, omniview:16 | $l | $(ratio "$l" "$base") | $t |"
  for m in ff opt omni; do
    "$BIN" preview --input "$f" --compare "$OUT/${name}_$m.vdb" --turntable 4 --elevation 30 --height 256 \
      --out "$OUT/${name}_${m}_####.png" > /dev/null
  done
done
rm -f "$OUT/judge_tmp.vdb" "$OUT/last.log"
