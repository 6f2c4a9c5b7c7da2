#!/usr/bin/env bash
# The cross test of the feed-forward models (docs/guide/feedforward.md): does
# a model carry *its* painting, or a look any painting would give? Every
# model's result on each held-out frame is judged toward every painting
# (worst of 8 views, ring:8:30, result over input; lower = nearer), and the
# result of a painting's own model must be the nearest of all the models'
# results to that painting.
#
#   bash tools/ff_cross_judge.sh OUTDIR MODEL=PAINTING [MODEL=PAINTING ...] [-- FRAME.vdb ...]
#   e.g. bash tools/ff_cross_judge.sh /tmp/cross \
#          models/starry_density.safetensors=../shared/data/styles/starry_night.jpg \
#          models/shipwreck_density.safetensors=../shared/data/styles/shipwreck.jpg
#
# Frames default to the held-out three of tools/ff_heldout.sh. Results of
# tools/ff_heldout.sh in OUTDIR (same names) are reused. Prints, per frame
# and painting, each model's worst view toward that painting and whether
# the painting's own model is strictly the nearest ("own nearest", "tie" or
# "OTHER nearer"; a tie does not count).
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 3 ] || { sed -n 2,17p "$0"; exit 2; }
out=$1
shift
pairs=()
while [ $# -gt 0 ] && [ "$1" != -- ]; do
  pairs+=("$1")
  shift
done
[ "${1:-}" = -- ] && shift
bin=${NST3D_BIN:-./target/release/nst3d}
threads=${NST3D_THREADS:-2}
if [ $# -eq 0 ]; then
  mapfile -t held_out < <(bash tools/ff_heldout_frames.sh)
  set -- "${held_out[@]}"
fi
mkdir -p "$out"
own=0 cases=0
for frame in "$@"; do
  name=$(basename "$(dirname "$(dirname "$frame")")")_$(basename "${frame%.vdb}")
  case "$frame" in ../shared/*) name=$(basename "${frame%.vdb}") ;; esac
  results=()
  for pair in "${pairs[@]}"; do
    model=${pair%%=*}
    net="$out/${name}_$(basename "${model%.safetensors}").vdb"
    [ -f "$net" ] || "$bin" --threads "$threads" volume --model "$model" --input "$frame" --out "$net" >/dev/null 2>&1
    results+=("$net")
  done
  for pair in "${pairs[@]}"; do
    painting=${pair#*=}
    worst=$("$bin" --threads "$threads" judge --style "$painting" --baseline "$frame" "${results[@]}" 2>/dev/null |
      awk '/ worst /{print $4}')
    read -r -a w <<<"$(echo $worst)"
    line="$name $(basename "${painting%.*}"):"
    mine="" others=9
    for i in "${!pairs[@]}"; do
      line+=" ${w[$i]}"
      if [ "${pairs[$i]#*=}" = "$painting" ]; then
        mine=${w[$i]}
      else
        others=$(awk -v a="$others" -v b="${w[$i]}" 'BEGIN{print (b < a) ? b : a}')
      fi
    done
    cases=$((cases + 1))
    verdict=$(awk -v m="$mine" -v o="$others" 'BEGIN{print (m < o) ? "own nearest" : (m == o) ? "tie" : "OTHER nearer"}')
    [ "$verdict" = "own nearest" ] && own=$((own + 1))
    echo "$line $verdict"
  done
done
echo "own model nearest its painting: $own of $cases"
