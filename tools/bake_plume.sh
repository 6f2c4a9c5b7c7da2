#!/usr/bin/env bash
# Bakes a Blender Mantaflow smoke plume to an OpenVDB cache with
# ../shared/tools/blender_bake_smoke.py, e.g. the 120-frame plume of the
# docs/guide/farm.md chunk measurement and the 96-resolution one of
# docs/guide/performance.md:
#
#   bash tools/bake_plume.sh data/plume120 48 120   # 32x32x48 domain, ~30 s
#   bash tools/bake_plume.sh data/plume96 96 40     # 64x64x96 domain, ~3 min
#
# Frames land in OUTDIR/data/fluid_data_####.vdb (grids density, temperature,
# flame, shadow, velocity), so nst3d reads them with
# --input 'OUTDIR/data/fluid_data_####.vdb'. The bake is deterministic: the
# first 40 frames at resolution 48 are byte-for-byte the voxels of the shared
# plume48. Keep OUTDIR outside the repository; the caches are not committed.
# Installs Debian's blender package (3.4) if blender is missing.
#
# Plume options after FRAMES bake a different plume with the project's own
# tools/blender_bake_plume.py (same scene, with knobs; see its header), e.g.
# the two plumes of docs/design/volumes.md:
#
#   bash tools/bake_plume.sh data/plumeA 64 48 --offset 0.4 0.25 --vorticity 0.3
#   bash tools/bake_plume.sh data/plumeB 56 48 --offset -0.4 0 --radius 0.2 \
#       --velocity 1.5 0 0 --alpha 2 --beta 3 --vorticity 0.15
#
# Options: --offset X Y, --radius R, --vorticity V, --velocity VX VY VZ,
# --alpha A, --beta B, --noise.
set -euo pipefail
if [ $# -lt 3 ]; then
  echo "usage: $0 OUTDIR RESOLUTION FRAMES [--offset X Y] [--radius R] [--vorticity V]" >&2
  echo "       [--velocity VX VY VZ] [--alpha A] [--beta B] [--noise]" >&2
  exit 2
fi
out=$1 res=$2 frames=$3
shift 3
here="$(cd "$(dirname "$0")/.." && pwd)"
if [ $# -eq 0 ]; then
  script="$here/../shared/tools/blender_bake_smoke.py"
  [ -f "$script" ] || { echo "bake_plume: $script is missing (the repo expects ../shared beside it)" >&2; exit 1; }
else
  script="$here/tools/blender_bake_plume.py"
fi

if ! command -v blender >/dev/null 2>&1; then
  echo "== installing blender"
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq blender >/dev/null
fi

mkdir -p "$out"
out="$(cd "$out" && pwd)"
# Blender reuses an existing cache instead of baking; start from an empty one.
if [ -d "$out/data" ] && [ -n "$(ls -A "$out/data")" ]; then
  echo "bake_plume: $out/data is not empty; remove it to bake again" >&2
  exit 1
fi
# From OUTDIR: with --noise Mantaflow writes waveletNoiseTile.bin into the current folder.
(cd "$out" && blender -b --factory-startup --python-exit-code 1 --python "$script" -- "$out" "$res" "$frames" "$@") >"$out/bake.log" 2>&1 \
  || { tail -20 "$out/bake.log" >&2; exit 1; }
n=$(ls "$out/data"/fluid_data_*.vdb 2>/dev/null | wc -l)
if [ "$n" -ne "$frames" ]; then
  echo "bake_plume: expected $frames frames in $out/data, found $n (log: $out/bake.log)" >&2
  exit 1
fi
echo "baked $n frames at resolution $res${*:+ ($*)}: $out/data/fluid_data_####.vdb"
