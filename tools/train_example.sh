#!/usr/bin/env bash
# Trains an example feed-forward model committed under models/: Starry Night
# on the 40 frames of the shared plume48 simulation, 48³ patches, two
# octaves, 4,000 steps (about 15 minutes on 2 cores), in density mode
# (models/starry_density.*, the one tools/example.sh uses) or velocity mode
# (models/starry_velocity.*). Rerunning after a kill resumes from the
# checkpoint beside the model.
#
#   bash tools/train_example.sh [density|velocity] [extra nst3d train arguments]
set -euo pipefail
cd "$(dirname "$0")/.."
MODE=${1:-density}
shift || true
bash tools/fetch_weights.sh
cargo build --release -q -p nst3d-cli
mkdir -p models
./target/release/nst3d train \
  --input '../shared/data/volumes/plume48/fluid_data_####.vdb' --frames 1-40 \
  --style ../shared/data/styles/starry_night.jpg \
  --mode "$MODE" --patch 48 --octaves 2 --steps 4000 --seed 0 \
  --out "models/starry_$MODE.safetensors" "$@"
