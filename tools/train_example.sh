#!/usr/bin/env bash
# Trains an example feed-forward model committed under models/ (the
# recipe of docs/guide/feedforward.md): Starry Night (or PAINTING) for
# $NST3D_TRAIN_MINUTES (default 55) minutes of wall clock on one thread, 32³
# patches seen through cameras from random directions, each as its whole
# frame is drawn (--absorption frame), a solid texture of period 32 beside
# the network, two octaves, the schedule sized to the budget, on
# three simulations — the shared plume48 (frames 1–40) and two bakes with
# other sizes and settings made here with Blender (plumeB: 56 voxels high,
# source off-centre with a sideways push; plume96: the shared scene at
# 64×64×96). Frames never trained on (smoke_000002/3, the plumeA and plumeC
# bakes of docs/design/feedforward.md) are the judge's. Rerunning after a kill
# resumes from the checkpoint beside the model.
#
#   bash tools/train_example.sh [density|velocity] [PAINTING] [extra nst3d train arguments]
#
# The bakes land in $NST3D_PLUMES (default ~/.cache/nst3d/plumes), outside
# the repository, and are reused when present (about 2 minutes to bake).
set -euo pipefail
cd "$(dirname "$0")/.."
MODE=${1:-density}
PAINTING=${2:-../shared/data/styles/starry_night.jpg}
shift 2 || shift $# || true
PLUMES=${NST3D_PLUMES:-$HOME/.cache/nst3d/plumes}
bash tools/fetch_weights.sh
cargo build --release -q -p nst3d-cli
bake() { # DIR RES FRAMES [options]: bake unless the frames are there
  local dir=$1 frames=$3
  [ "$(ls "$dir"/data/fluid_data_*.vdb 2>/dev/null | wc -l)" -eq "$frames" ] && return 0
  rm -rf "$dir"
  bash tools/bake_plume.sh "$@"
}
bake "$PLUMES/plumeB" 56 48 --offset -0.4 0 --radius 0.2 --velocity 1.5 0 0 --alpha 2 --beta 3 --vorticity 0.15
bake "$PLUMES/plume96" 96 40
name=$(basename "${PAINTING%.*}")
name=${name%_night}
mkdir -p models
./target/release/nst3d --threads 1 train \
  --input '../shared/data/volumes/plume48/fluid_data_####.vdb' --frames 1-40 \
  --input "$PLUMES/plumeB/data/fluid_data_####.vdb" --frames 1-48 \
  --input "$PLUMES/plume96/data/fluid_data_####.vdb" --frames 1-40 \
  --style "$PAINTING" --mode "$MODE" --minutes "${NST3D_TRAIN_MINUTES:-55}" --seed 0 \
  --view-axes sphere --absorption frame --texture 32 \
  --out "models/${name}_$MODE.safetensors" "$@"
