#!/usr/bin/env bash
# The feed-forward held-out judge: how far a stylized file moved towards a
# painting, seen from 8 cameras all around that no optimisation or training
# used (ring:8:30 — 8 azimuths at 30° elevation), with the real VGG-19 Gram
# style loss. Per view: loss(result) / loss(input); the score is the worst
# (largest) view's ratio — lower is stronger, 1 is unchanged.
#
#   bash tools/ff_judge.sh PAINTING INPUT.vdb RESULT.vdb [RESULT.vdb ...]
#
# Prints, per RESULT, "RESULT worst W mean M views r1 ... r8". The judge
# reads files only; which method made them does not matter.
set -euo pipefail
cd "$(dirname "$0")/.."
PAINTING=$1; INPUT=$2; shift 2
BIN=${NST3D_BIN:-./target/release/nst3d}
EVAL=ring:8:30
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
# Per-view style losses of a file (the "before" side of a one-iteration run).
views() {
  "$BIN" volume --input "$1" --style "$PAINTING" --mode density --upsample 1 --iters 1 --octaves 1 \
    --eval-cameras "$EVAL" --out "$tmp/j.vdb" 2>/dev/null |
    sed -n 's/^held-out cameras .*: per view \(.*\); worst view .*/\1/p' | tr ' ' '\n' | sed 's/->.*//'
}
mapfile -t base < <(views "$INPUT")
[ ${#base[@]} -eq 8 ] || { echo "ff_judge: could not score $INPUT" >&2; exit 1; }
for r in "$@"; do
  mapfile -t res < <(views "$r")
  [ ${#res[@]} -eq 8 ] || { echo "ff_judge: could not score $r" >&2; exit 1; }
  paste <(printf '%s\n' "${res[@]}") <(printf '%s\n' "${base[@]}") |
    awk -v name="$r" '{ r = $1 / $2; s = s sprintf(" %.3f", r); m += r; if (r > w) w = r }
      END { printf "%s worst %.3f mean %.3f views%s\n", name, w, m / NR, s }'
done
