#!/usr/bin/env bash
# Builds docs/img/strength_*.png from the preview sheets that
# tools/strength_runs.sh wrote into RUN_DIR (docs/design/volumes.md).
#
#     bash tools/strength_strips.sh RUN_DIR [PYTHON]
#
# PYTHON needs Pillow and NumPy (default python3; a throwaway venv works:
# python3 -m venv /tmp/pilvenv && /tmp/pilvenv/bin/pip install pillow numpy).
set -euo pipefail
S=${1:?folder with the preview sheets}
PY=${2:-python3}
cd "$(dirname "$0")/.."
O=docs/img
strip() { "$PY" tools/strip.py "$@"; }

strip $O/strength_knob_velocity.png --before \
  $S/v_k0.5.png="0.5 subtle" $S/v_k1.png="1 default" $S/v_k1.5.png="1.5 strong" $S/v_k2.png=2
strip $O/strength_knob_density.png --before \
  $S/d_k0.5.png="0.5 subtle" $S/d_k1.png="1 default" $S/d_k1.5.png="1.5 strong" $S/d_k2.png=2
strip $O/strength_style_scale.png --before \
  --row velocity $S/v_ss025.png=0.25 $S/v_def.png="0.5 (default)" $S/v_ss100.png=1.0 \
  --row density $S/d_ss025.png=0.25 $S/d_def.png="0.5 (default)" $S/d_ss100.png=1.0
strip $O/strength_vmax.png --before \
  --row velocity $S/v_vmax1.png=1 $S/v_vmax2.png=2 $S/v_def.png="3.84 (default)" $S/v_vmax6.png=5.76 $S/v_vmax8.png=8
strip $O/strength_density_range.png --before \
  --row density $S/d_s0713.png=0.75-1.25 $S/d_s0515.png=0.5-1.5 $S/d_def.png="0-2 (default)" $S/d_s0030.png=0-3
strip $O/strength_octaves.png --before \
  --row velocity $S/v_oct1.png=1 $S/v_def.png="2 (default)" $S/v_oct3.png=3 \
  --row density $S/d_oct1.png=1 $S/d_def.png="2 (default)" $S/d_oct3.png=3
strip $O/strength_iters.png --before \
  --row velocity $S/v_it10.png=10 $S/v_def.png="20 (default)" $S/v_it40.png=40 $S/v_it60.png=60 \
  --row density $S/d_it10.png=10 $S/d_def.png="20 (default)" $S/d_it40.png=40 $S/d_it60.png=60
strip $O/strength_layers.png --before \
  --row velocity $S/v_lay12.png=relu1_1,2_1 $S/v_def.png="all 4 (default)" $S/v_lay34.png=relu3_1,4_1 \
  --row density $S/d_lay12.png=relu1_1,2_1 $S/d_def.png="all 4 (default)" $S/d_lay34.png=relu3_1,4_1
strip $O/strength_mode.png --before $S/d_def.png=density $S/v_def.png="velocity (default)"
ls -l $O/strength_*.png
