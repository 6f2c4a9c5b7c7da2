#!/usr/bin/env bash
# The feed-forward network's held-out judge (docs/guide/feedforward.md): a
# model against the `omniview:16` optimisation it stands in for, on frames it
# never saw, from 8 cameras around each frame (ring:8:30), each result's
# style loss over the input's (lower = nearer the painting), and a picture
# per frame: input | network | optimisation, front (top) and side (bottom).
#
#   bash tools/ff_heldout.sh OUTDIR MODEL PAINTING [FRAME.vdb ...]
#
# Frames default to the three the shipped models never saw: smoke_000002,
# smoke_000003 and frame 30 of the plumeA bake (tools/bake_plume.sh; baked
# into $NST3D_PLUMES, default ~/.cache/nst3d/plumes, when missing).
# Optimisations already in OUTDIR are reused. Prints one line per frame:
#   frame network_worst omniview_worst network_median omniview_median
# and writes OUTDIR/<frame>_<model>.png. Needs the release binary and, for the
# pictures, python3 with Pillow (NST3D_PYTHON, default .venv-torch/bin/python).
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 3 ] || { sed -n 2,17p "$0"; exit 2; }
out=$1 model=$2 painting=$3
shift 3
bin=${NST3D_BIN:-./target/release/nst3d}
py=${NST3D_PYTHON:-.venv-torch/bin/python}
threads=${NST3D_THREADS:-2}
if [ $# -eq 0 ]; then
  mapfile -t held_out < <(bash tools/ff_heldout_frames.sh)
  set -- "${held_out[@]}"
fi
mkdir -p "$out"
style=$(basename "${painting%.*}")
for frame in "$@"; do
  name=$(basename "$(dirname "$(dirname "$frame")")")_$(basename "${frame%.vdb}")
  case "$frame" in ../shared/*) name=$(basename "${frame%.vdb}") ;; esac
  omni="$out/${name}_${style}_omniview.vdb" net="$out/${name}_$(basename "${model%.safetensors}").vdb"
  [ -f "$omni" ] || "$bin" --threads "$threads" volume --input "$frame" --style "$painting" --mode density \
    --cameras omniview:16 --out "$omni" >/dev/null 2>&1
  "$bin" --threads "$threads" volume --model "$model" --input "$frame" --out "$net" >/dev/null 2>&1
  scores=$("$bin" --threads "$threads" judge --style "$painting" --baseline "$frame" "$net" "$omni" 2>/dev/null |
    awk '/ worst /{print $4, $6}')
  read -r nw nm ow om <<<"$(echo $scores)"
  echo "$name $nw $ow $nm $om"
  for v in net omni; do
    "$bin" --threads "$threads" preview --input "$frame" --compare "${!v}" --turntable 4 --elevation 15 \
      --height 320 --out "$out/.${name}_$v.####.png" >/dev/null 2>&1
  done
  "$py" - "$out/.${name}" "$out/${name}_$(basename "${model%.safetensors}").png" <<'PY'
import sys
from PIL import Image
pre, dst = sys.argv[1], sys.argv[2]
rows = []
for view in (1, 2):  # front, side
    net = Image.open(f"{pre}_net.{view:04d}.png")
    omni = Image.open(f"{pre}_omni.{view:04d}.png")
    w = net.width // 2
    row = Image.new("RGB", (3 * w, net.height))
    row.paste(net, (0, 0))
    row.paste(omni.crop((w, 0, 2 * w, omni.height)), (2 * w, 0))
    rows.append(row)
sheet = Image.new("RGB", (rows[0].width, sum(r.height for r in rows)))
for i, r in enumerate(rows):
    sheet.paste(r, (0, i * r.height))
sheet.save(dst)
PY
  rm -f "$out/.${name}"_*.png
done
