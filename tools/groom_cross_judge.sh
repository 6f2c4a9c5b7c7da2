#!/usr/bin/env bash
# The cross test of a groom's look: does a groom take *its* style's look, or
# a look any target gives it? (docs/guide/strands.md, "What to expect")
#
# Stylizes GROOM toward each geometric style of tools/strand_ref/styles.py
# (stripes of two widths, a spiral, a triangle tessellation, checks), each
# shared painting and a textureless grey ramp (the control), then judges
# every result against every style with tools/strand_ref/judge.py, three
# times: a VGG-19 Gram loss, the distance between stroke-direction
# histograms, and the misalignment of the render's strokes with the style's
# strokes laid over the hair's box as the orientation term lays them; each of
# the hair's box in nine frontal views inside the preset's camera range (the
# views the optimiser faced), as result / input. It then
# checks every pair of styles A, B: the result toward A must be nearer A
# than the result toward B is, by 10 % for two geometric styles and 5 %
# where a painting is in the pair, and the ramp must be nearest no style.
#
#   bash tools/groom_cross_judge.sh OUTDIR GROOM MESH|- y|z ANGLE [nst3d strands options...]
#   e.g. bash tools/groom_cross_judge.sh /tmp/x ../shared/data/grooms/monkey_curly.ply \
#          ../shared/data/grooms/monkey_curly_mesh.obj z 10 --render-size 300 --iters 30
#
# ANGLE is the preset's camera half-range in degrees (10 for short hair and
# grass, 15 for the fur ball); with AROUND=N (a 360-degree preset) the
# judge looks from N azimuths all round and ANGLE is the polar half-range
# (20 for short-hair-360). Needs the PyTorch environment of
# tools/bench_common.sh (.venv-torch, made on first use). Runs two jobs at a
# time on one thread each; finished pieces are kept, so a rerun with the
# same OUTDIR resumes. Set STYLES to judge a subset. With a mesh the judge
# draws, as nst3d does, only strands whose root faces the camera: CULL is
# the preset's visibility threshold (0.3 by default, Table 1's short hair;
# 0.5 for the fur ball and grass).
set -euo pipefail
[ $# -ge 5 ] || { echo "usage: $0 OUTDIR GROOM MESH|- y|z ANGLE [nst3d strands options...]" >&2; exit 2; }
OUT=$(realpath -m "$1"); GROOM=$(realpath -m "$2"); MESH=$3; UP=$4; ANGLE=$5; shift 5
[ "$MESH" = - ] || MESH=$(realpath -m "$MESH")
cd "$(dirname "$0")/.."
BIN=${NST3D_BIN:-./target/release/nst3d}
[ -x "$BIN" ] || { echo "groom_cross_judge: no nst3d binary at $BIN (cargo build --release)" >&2; exit 1; }
[ -f "$GROOM" ] || { echo "groom_cross_judge: no groom at $GROOM" >&2; exit 1; }
[[ "$GROOM" == *.ply ]] || { echo "groom_cross_judge: the judge reads .ply grooms; $GROOM is not one" >&2; exit 1; }
source tools/bench_common.sh   # sets PY (a Python with torch) and builds nst3d
"$PY" -c "import PIL, scipy" 2>/dev/null || "$PY" -m pip install -q pillow scipy
GEOMETRIC=(stripes stripes_wide spiral triangles checks)
PAINTINGS=(starry_night shipwreck woman_with_hat)
read -r -a ALL <<< "${STYLES:-${GEOMETRIC[*]} ${PAINTINGS[*]} ramp}"
mkdir -p "$OUT/styles"
"$PY" tools/strand_ref/styles.py "$OUT/styles"
style_of() { [ -f "$OUT/styles/$1.png" ] && echo "$OUT/styles/$1.png" || echo "../shared/data/styles/$1.jpg"; }
mesh_args=(); [ "$MESH" = - ] || mesh_args=(--mesh "$MESH")
cull_args=(); [ "$MESH" = - ] || cull_args=(--cull "${CULL:-0.3}")
stylize() {
  local s=$1; shift
  [ -f "$OUT/$s.ply" ] && return 0
  "$BIN" --threads 1 strands --groom "$GROOM" "${mesh_args[@]}" --up "$UP" --style "$(style_of "$s")" "$@" \
    --out "$OUT/$s.ply" > "$OUT/$s.log" 2>&1 ||
    { echo "groom_cross_judge: stylizing toward $s failed, see $OUT/$s.log" >&2; return 1; }
}
for ((i = 0; i < ${#ALL[@]}; i += 2)); do
  stylize "${ALL[i]}" "$@" & a=$!
  b=""; if ((i + 1 < ${#ALL[@]})); then stylize "${ALL[i+1]}" "$@" & b=$!; fi
  wait $a; [ -z "$b" ] || wait $b
done
args=()
# The judge lays each style as the optimiser did: at the run's
# --style-scale, else the scale the run printed (the preset's).
scale=""; prev=""; for o in "$@"; do [ "$prev" = --style-scale ] && scale=$o; prev=$o; done
[ -n "$scale" ] || scale=$(sed -n 's/^the look: .*style scale \([0-9.]*\)$/\1/p' "$OUT/${ALL[0]}.log" | head -1)
[ -n "$scale" ] || { echo "groom_cross_judge: $OUT/${ALL[0]}.log does not say its style scale" >&2; exit 1; }
args+=(--style-scale "$scale")
for s in "${ALL[@]}"; do args+=(--result "$s=$OUT/$s.ply"); done
for s in "${ALL[@]}"; do [ "$s" = ramp ] || args+=(--style "$s=$(style_of "$s")"); done
# Three judges: the Gram loss (texture statistics), the distance of the
# stroke-direction histograms (which way the strands and strokes run) and
# the strokes' misalignment in place (whether they run where the style's do).
for judge in gram orient layout; do
  echo "== judge: $judge"
  "$PY" tools/strand_ref/judge.py --judge "$judge" --rest "$GROOM" "${args[@]}" --up "$UP" --ang "$ANGLE" ${AROUND:+--around "$AROUND"} --crop "${cull_args[@]}" \
    --painting-margin 0.05 --paintings "$(IFS=,; echo "${PAINTINGS[*]}")" \
    --sheet "$OUT/sheet.png" --json "$OUT/judge_$judge.json" | tee "$OUT/judge_$judge.txt"
done
