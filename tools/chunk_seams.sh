#!/usr/bin/env bash
# Runs one sequence as a single `nst3d volume --frames` run and as farm chunks
# with --warmup K, then compares them frame by frame with tools/seam_compare.py
# (docs/guide/farm.md):
#
#   NST3D=target/release/nst3d bash tools/chunk_seams.sh OUTROOT 'plume/data/fluid_data_####.vdb' \
#       1-120 "1-30 31-60 61-90 91-120" 8 --iters 4 --octaves 1 --ema-settle
#
# Everything after K is passed to every run, so the single run and the chunks
# use the same settings. Outputs: OUTROOT/single/s_####.vdb,
# OUTROOT/k<K>/s_####.vdb, times (wall, user+sys CPU) in OUTROOT/times.txt,
# the comparison in OUTROOT/k<K>.txt. Frames already written are skipped by
# nst3d itself, so a second call with another K reuses the single run.
set -euo pipefail
if [ $# -lt 5 ]; then
  echo "usage: $0 OUTROOT INPUT_PATTERN FRAMES \"CHUNK CHUNK ...\" K [nst3d volume flags...]" >&2
  exit 2
fi
root=$1 input=$2 frames=$3 chunks=$4 k=$5
shift 5
here="$(cd "$(dirname "$0")/.." && pwd)"
nst3d=${NST3D:-$here/target/release/nst3d}
style=${STYLE:-$here/../shared/data/styles/starry_night.jpg}
mkdir -p "$root"

run() { # label, out dir, extra flags...
  local label=$1 out=$2
  shift 2
  /usr/bin/time -f "$label: wall %e s, cpu user+sys %U+%S s, maxrss %M KB" -a -o "$root/times.txt" \
    "$nst3d" --threads 2 volume --input "$input" --frames "$frames" --style "$style" \
    --out "$root/$out/s_####.vdb" "$@"
}

run "single $frames" single "$@" 2>"$root/single.log"
for c in $chunks; do
  run "chunk $c warmup $k" "k$k" --chunk "$c" --warmup "$k" "$@" 2>"$root/k$k-$c.log"
done

# The frames on both sides of every seam between consecutive chunks.
seams=$(for c in $chunks; do echo "$c"; done | awk -F- 'NR>1 {printf "%s%d,%d", sep, prev, $1; sep=","} {prev=$2}')
"${PYTHON:-/usr/bin/python3}" "$here/tools/seam_compare.py" "$root/single/s_####.vdb" "$root/k$k/s_####.vdb" "$input" "$frames" \
  --seams "$seams" | tee "$root/k$k.txt"
