#!/usr/bin/env bash
# Judges the reference arms tools/device/ff_device.sh brought back, as the
# shipped models are judged: each state dict into an nst3d model
# (tools/ff_ref/to_nst3d.py, the painting's shipped model as the template,
# patch and steps set from the arm), then tools/ff_heldout.sh on the three
# held-out frames. One judge folder per painting, so its omniview:16
# optimisations are made once.
#
#   bash tools/device/judge_arms.sh RESULTS_DIR OUTDIR
set -euo pipefail
cd "$(dirname "$0")/../.."
res=$1 out=$2
py=${NST3D_PYTHON:-.venv-torch/bin/python}
mkdir -p "$out"
for pt in "$res"/*.pt; do
  arm=$(basename "$pt" .pt)
  painting=${arm%%_p[0-9]*}
  case "$painting" in starry) file=starry_night ;; woman) file=woman_with_hat; painting=woman_with_hat ;; *) file=$painting ;; esac
  patch=$(echo "$arm" | sed -E 's/.*_p([0-9]+)_.*/\1/')
  steps=$(($(wc -l < "$res/$arm.log.csv")))
  model="$out/ref_$arm.safetensors"
  "$py" tools/ff_ref/to_nst3d.py pt2st "$pt" "models/${painting}_density.safetensors" "$model.tmp"
  "$py" - "$model.tmp" "$model" "$patch" "$steps" <<'PY'
import sys
sys.path.insert(0, "tools/ff_ref")
from to_nst3d import read_st, write_st
meta, t = read_st(sys.argv[1])
meta.update(patch=sys.argv[3], steps=sys.argv[4], trained_by="tools/ff_ref/ff_reference.py")
write_st(sys.argv[2], meta, t)
PY
  rm -f "$model.tmp"
  echo "# $arm ($steps steps, patch $patch)"
  bash tools/ff_heldout.sh "$out/$file" "$model" "../shared/data/styles/$file.jpg"
done
