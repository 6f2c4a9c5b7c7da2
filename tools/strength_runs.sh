#!/usr/bin/env bash
# Runs the settings of docs/design/volumes.md one at
# a time and prints one line per run: name, UTC time, optimised-view loss
# before -> after (ratio), held-out ring:6:30 mean loss before -> after
# (ratio). v_k* and d_k* are the --strength knob; *_omni are the
# --cameras omniview:16 rows of "Style strength from the optimised view
# and from views it never saw" (there the optimised loss is the sum over
# the 16 cameras).
#
#     bash tools/strength_runs.sh NST3D_BINARY OUT_DIR [NAME ...]
#
# With NAMEs it runs only those settings (see the table below). Each run
# writes OUT_DIR/NAME.vdb, the preview sheet OUT_DIR/NAME.png and the log
# OUT_DIR/NAME.log. Pictures: bash tools/strength_strips.sh OUT_DIR.
set -euo pipefail
BIN=${1:?nst3d binary}
OUT=${2:?output folder}
shift 2
DATA=${DATA:-$(cd "$(dirname "$0")/.." && pwd)/../shared/data}
mkdir -p "$OUT"

# name | arguments after the common ones
SETTINGS='
v_def|--mode velocity
v_ss025|--mode velocity --style-scale 0.25
v_ss100|--mode velocity --style-scale 1.0
v_vmax1|--mode velocity --vmax 1
v_vmax1.92|--mode velocity --vmax 1.92
v_vmax2|--mode velocity --vmax 2
v_vmax8|--mode velocity --vmax 8
v_oct1|--mode velocity --octaves 1
v_oct3|--mode velocity --octaves 3
v_it10|--mode velocity --iters 10
v_it30|--mode velocity --iters 30
v_it40|--mode velocity --iters 40
v_it60|--mode velocity --iters 60
v_lay12|--mode velocity --layers relu1_1,relu2_1
v_lay34|--mode velocity --layers relu3_1,relu4_1
d_def|--mode density
d_ss025|--mode density --style-scale 0.25
d_ss100|--mode density --style-scale 1.0
d_s0515|--mode density --smin 0.5 --smax 1.5
d_s0416|--mode density --smin 0.4 --smax 1.6
d_s0030|--mode density --smin 0 --smax 3
d_oct1|--mode density --octaves 1
d_oct3|--mode density --octaves 3
d_it10|--mode density --iters 10
d_it30|--mode density --iters 30
d_it40|--mode density --iters 40
d_it60|--mode density --iters 60
d_lay12|--mode density --layers relu1_1,relu2_1
d_lay34|--mode density --layers relu3_1,relu4_1
v_vmax6|--mode velocity --vmax 5.76
v_vmax6_it40|--mode velocity --vmax 5.76 --iters 40
v_vmax8_it40|--mode velocity --vmax 7.68 --iters 40
v_vmax6_it30|--mode velocity --vmax 5.76 --iters 30
d_s0713|--mode density --smin 0.75 --smax 1.25
d_s0025_it30|--mode density --smin 0 --smax 2.5 --iters 30
d_s0030_it40|--mode density --smin 0 --smax 3 --iters 40
v_k0.5|--mode velocity --strength 0.5
v_k1|--mode velocity --strength 1
v_k1.5|--mode velocity --strength 1.5
v_k2|--mode velocity --strength 2
d_k0.5|--mode density --strength 0.5
d_k1|--mode density --strength 1
d_k1.5|--mode density --strength 1.5
d_k2|--mode density --strength 2
v_omni|--mode velocity --cameras omniview:16
d_omni|--mode density --cameras omniview:16
'

ratio() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.3f", b / a }'; }

echo "$SETTINGS" | while IFS='|' read -r name args; do
  [ -n "$name" ] || continue
  if [ $# -gt 0 ] && ! printf '%s\n' "$@" | grep -qx "$name"; then continue; fi
  # shellcheck disable=SC2086
  "$BIN" --threads 2 volume \
    --input "$DATA/volumes/smoke_000003.vdb" \
    --style "$DATA/styles/starry_night.jpg" \
    --eval-cameras ring:6:30 \
    --out "$OUT/$name.vdb" --preview "$OUT/$name.png" $args >"$OUT/$name.log" 2>&1
  read -r ob oa < <(sed -n 's/.*; style loss \([^ ]*\) -> \([^ ]*\) .*/\1 \2/p' "$OUT/$name.log")
  read -r hb ha < <(sed -n 's/^held-out.*mean style loss \([^ ]*\) -> \([^ ]*\)$/\1 \2/p' "$OUT/$name.log")
  printf '%s\t%s\t%s -> %s (%s)\t%s -> %s (%s)\n' "$name" "$(date -u +%H:%M)" \
    "$ob" "$oa" "$(ratio "$ob" "$oa")" "$hb" "$ha" "$(ratio "$hb" "$ha")"
done
