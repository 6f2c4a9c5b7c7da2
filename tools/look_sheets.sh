#!/usr/bin/env bash
# The look at the defaults (docs/design/volumes.md): both modes on three frames,
# each run alone with the CLI defaults and --threads 2. Prints each run's
# note and loss line; writes the preview sheets into OUT_DIR and their grey
# copies into docs/img/look_FRAME_MODE.png.
#
#     bash tools/look_sheets.sh NST3D_BINARY OUT_DIR [PYTHON]
#
# PYTHON needs Pillow and NumPy (see tools/strength_strips.sh).
set -euo pipefail
BIN=${1:?nst3d binary}
OUT=${2:?output folder}
PY=${3:-python3}
cd "$(dirname "$0")/.."
DATA=${DATA:-../shared/data}
mkdir -p "$OUT"
for f in smoke_000003 smoke_000002 plume48/fluid_data_0030; do
  n=$(basename "$f")
  for m in velocity density; do
    "$BIN" --threads 2 volume --input "$DATA/volumes/$f.vdb" \
      --style "$DATA/styles/starry_night.jpg" --mode "$m" \
      --out "$OUT/${n}_$m.vdb" --preview "$OUT/${n}_$m.png" >"$OUT/${n}_$m.log" 2>&1
    echo "== $n $m $(date -u +%H:%M) UTC"
    grep -v '^\[' "$OUT/${n}_$m.log"
    "$PY" tools/strip.py --sheet "$OUT/${n}_$m.png" "docs/img/look_${n}_$m.png"
  done
done
ls -l docs/img/look_*.png
