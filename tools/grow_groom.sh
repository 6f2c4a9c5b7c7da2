#!/usr/bin/env bash
# Grows a particle-hair groom on a mesh with ../shared/tools/blender_groom.py
# (Blender's particle hair: COUNT guides with CHILDREN interpolated children
# each, a kink, a seed), z up as Blender writes it — stylize it with --up z.
# The second test groom (straight hair on the monkey head, next to the
# shared curly one):
#
#   bash tools/grow_groom.sh data/grooms monkey_straight monkey 500 8 NO 7
#
# writes OUTDIR/NAME.ply (4,500 strands x 17 points) and OUTDIR/NAME_mesh.obj
# in a few seconds. Deterministic in the seed. Keep OUTDIR outside the
# repository; grooms are not committed. Installs Debian's blender if missing.
set -euo pipefail
if [ $# -ne 7 ]; then
  echo "usage: $0 OUTDIR NAME monkey|sphere COUNT CHILDREN NO|CURL|RADIAL|WAVE|BRAID|SPIRAL SEED" >&2
  exit 2
fi
cd "$(dirname "$0")/.."
if ! command -v blender >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
  $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq blender >/dev/null
fi
mkdir -p "$1"
blender -b --factory-startup --python ../shared/tools/blender_groom.py -- "$@" >/dev/null
ls -l "$1/$2.ply" "$1/$2_mesh.obj"
