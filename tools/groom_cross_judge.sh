#!/usr/bin/env bash
# Issue 27's cross-painting test: does a groom take *its* painting's look, or
# a look any target gives it? (docs/STRANDS.md, "Three paintings, one look")
#
# Stylizes GROOM toward each of the three shared paintings and toward a
# control with no strokes at all (a grey ramp, luminance 0.2 -> 0.7), then
# judges every result against every painting with `nst3d preview --style`
# (8 turntable views at 15 degrees, 512 px; none an optimisation view).
#
#   bash tools/groom_cross_judge.sh OUTDIR GROOM MESH y|z [nst3d strands options...]
#   e.g. (from the repository) bash tools/groom_cross_judge.sh /tmp/x \
#          ../shared/data/grooms/monkey_curly.ply ../shared/data/grooms/monkey_curly_mesh.obj z \
#          --render-size 300 --iters 30
#
# Prints one table per judge (whole picture, hair only, hair only tone
# matched): rows are what the groom was stylized toward, columns the
# painting it is judged against, cells the median over the 8 views of
# result / input (lower is nearer). A look of the painting's own shows as a
# diagonal clearly below its column's other rows, the ramp row above all.
# Runs one job at a time on one thread; finished pieces are kept, so a
# rerun with the same OUTDIR resumes.
set -euo pipefail
[ $# -ge 4 ] || { echo "usage: $0 OUTDIR GROOM MESH y|z [nst3d strands options...]" >&2; exit 2; }
# Paths as given, from the caller's directory (the script then runs from the repository).
OUT=$(realpath -m "$1"); GROOM=$(realpath -m "$2"); MESH=$(realpath -m "$3"); UP=$4; shift 4
cd "$(dirname "$0")/.."
BIN=${NST3D_BIN:-./target/release/nst3d}
PAINTINGS=(starry_night shipwreck woman_with_hat)
mkdir -p "$OUT"
# The control: a textureless grey ramp (written with the standard library only).
[ -f "$OUT/ramp.png" ] || python3 - "$OUT/ramp.png" <<'EOF'
import struct, sys, zlib
w, h = 760, 600
row = bytes(int((0.2 + 0.5 * x / w) * 255) for x in range(w) for _ in range(3))
raw = b"".join(b"\0" + row for _ in range(h))
chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xffffffff)
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)) \
    + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
open(sys.argv[1] + ".tmp", "wb").write(png)
import os; os.replace(sys.argv[1] + ".tmp", sys.argv[1])
EOF
style_of() { if [ "$1" = ramp ]; then echo "$OUT/ramp.png"; else echo "../shared/data/styles/$1.jpg"; fi; }
for r in "${PAINTINGS[@]}" ramp; do
  [ -f "$OUT/$r.usda" ] || "$BIN" --threads 1 strands --groom "$GROOM" --mesh "$MESH" --up "$UP" \
    --style "$(style_of "$r")" "$@" --out "$OUT/$r.usda" > "$OUT/$r.log" 2>&1 ||
    { echo "groom_cross_judge: stylizing toward $r failed, see $OUT/$r.log" >&2; exit 1; }
  for p in "${PAINTINGS[@]}"; do
    j="$OUT/j_${r}_vs_$p"
    grep -q "tone matched" "$j.log" 2>/dev/null && continue
    mkdir -p "$j"
    "$BIN" --threads 1 preview --input "$GROOM" --compare "$OUT/$r.usda" --mesh "$MESH" --up "$UP" \
      --turntable 8 --elevation 15 --height 512 --style "../shared/data/styles/$p.jpg" \
      --out "$j/j_####.png" > "$j.log" 2>&1 ||
      { echo "groom_cross_judge: judging $r against $p failed, see $j.log" >&2; exit 1; }
  done
done
# The judge's three lines, in order: whole picture, hair only, hair only tone matched.
for k in 1 2 3; do
  printf '\n%s\n' "$(echo "whole picture|hair only|hair only, tone matched" | cut -d'|' -f$k)"
  printf '%-16s' "stylized toward"; printf ' | %-14s' "${PAINTINGS[@]}"; echo
  for r in "${PAINTINGS[@]}" ramp; do
    printf '%-16s' "$r"
    for p in "${PAINTINGS[@]}"; do
      printf ' | %-14s' "$(grep -o 'median [0-9.]*' "$OUT/j_${r}_vs_$p.log" | sed -n "${k}p" | cut -d' ' -f2)"
    done
    echo
  done
done
