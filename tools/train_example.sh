#!/usr/bin/env bash
# Trains the example feed-forward model committed as models/starry_velocity.*:
# velocity mode, Starry Night, on the 40 frames of the shared plume48
# simulation, 48³ patches, two octaves, 4,000 steps (about 20 minutes on 2 cores).
# Rerunning after a kill resumes from models/starry_velocity.safetensors.ckpt.
#
#   bash tools/train_example.sh [extra nst3d train arguments]
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/fetch_weights.sh
cargo build --release -q -p nst3d-cli
mkdir -p models
./target/release/nst3d train \
  --input '../shared/data/volumes/plume48/fluid_data_####.vdb' --frames 1-40 \
  --style ../shared/data/styles/starry_night.jpg \
  --mode velocity --patch 48 --octaves 2 --steps 4000 --seed 0 \
  --out models/starry_velocity.safetensors "$@"
