#!/usr/bin/env bash
# Judges a groom stylized with a two-painting style map region by region:
# each region's strands (map value below 0.5: the first painting's; above:
# the second's) drawn alone from the judge's nine frontal views, their
# strokes' misalignment against each painting laid over the region's box
# on the rest groom (as the optimiser lays it), relative to the rest groom. A region passes when
# it is nearer its own painting than the other one, and nearer its own
# painting than the one-painting result of the other painting is.
#
#   bash tools/groom_map_judge.sh OUT GROOM MESH|- y|z ANGLE MAP.txt STYLE_A STYLE_B \
#        MAPPED.ply SINGLE_A.ply SINGLE_B.ply [--style-scale S] [--cull C]
#
# MAP.txt holds the map value of every strand, in file order (what
# `nst3d strands --style-map` read). Needs the Python with torch that
# tools/bench_common.sh sets up.
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 11 ] || { sed -n '2,15p' "$0" >&2; exit 2; }
OUT=$1 GROOM=$2 MESH=$3 UP=$4 ANGLE=$5 MAP=$6 STYLE_A=$7 STYLE_B=$8 MAPPED=$9 SINGLE_A=${10} SINGLE_B=${11}
shift 11
scale=1; cull=()
while [ $# -gt 0 ]; do
  case $1 in
    --style-scale) scale=$2; shift 2 ;;
    --cull) cull=(--cull "$2"); shift 2 ;;
    *) echo "groom_map_judge: unknown option $1" >&2; exit 2 ;;
  esac
done
for f in "$GROOM" "$MAP" "$STYLE_A" "$STYLE_B" "$MAPPED" "$SINGLE_A" "$SINGLE_B"; do
  [ -f "$f" ] || { echo "groom_map_judge: no file $f" >&2; exit 1; }
done
PY=${TORCH_PYTHON:-python3}
mkdir -p "$OUT"
for region in A:0:0.4999 B:0.5001:1; do
  name=${region%%:*}
  "$PY" tools/strand_ref/judge.py --judge layout --rest "$GROOM" --up "$UP" --ang "$ANGLE" --crop "${cull[@]}" \
    --style-scale "$scale" --region "$MAP:${region#*:}" \
    --result "mapped=$MAPPED" --result "single_a=$SINGLE_A" --result "single_b=$SINGLE_B" \
    --style "a=$STYLE_A" --style "b=$STYLE_B" --json "$OUT/region_$name.json" > "$OUT/region_$name.txt"
done
"$PY" - "$OUT" <<'EOF'
import json, sys
out = sys.argv[1]
ok_all = True
for name, own, other, single_other in (('A', 'a', 'b', 'single_b'), ('B', 'b', 'a', 'single_a')):
    rel = json.load(open(f'{out}/region_{name}.json'))['rel']
    m = rel['mapped']
    near_own = m[own] < m[other]
    beats_single = m[own] < rel[single_other][own]
    ok = near_own and beats_single
    ok_all &= ok
    print(f'region {name}: mapped result / rest against its own painting {m[own]:.3f}, against the other {m[other]:.3f}; '
          f'the other painting\'s one-painting result against this painting {rel[single_other][own]:.3f}; '
          f'this painting\'s one-painting result {rel["single_" + own][own]:.3f} -> {"ok" if ok else "FAIL"}')
print('both regions pass' if ok_all else 'a region fails')
EOF
