#!/usr/bin/env bash
# The three frames the shipped feed-forward models never saw, one path a
# line: smoke_000002, smoke_000003 and frame 30 of the plumeA bake
# (tools/bake_plume.sh; baked into $NST3D_PLUMES, default
# ~/.cache/nst3d/plumes, when missing). Paths are relative to the repository.
set -euo pipefail
cd "$(dirname "$0")/.."
plumes=${NST3D_PLUMES:-$HOME/.cache/nst3d/plumes}
[ -f "$plumes/plumeA/data/fluid_data_0030.vdb" ] ||
  bash tools/bake_plume.sh "$plumes/plumeA" 64 48 --offset 0.4 0.25 --vorticity 0.3 >/dev/null
printf '%s\n' ../shared/data/volumes/smoke_000002.vdb ../shared/data/volumes/smoke_000003.vdb \
  "$plumes/plumeA/data/fluid_data_0030.vdb"
