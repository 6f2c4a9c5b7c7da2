#!/usr/bin/env bash
# Stylizes the bundled example (a real smoke frame from ../shared/data) with
# Van Gogh's Starry Night, in both modes. Outputs land in out/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/fetch_weights.sh
cargo build --release -q -p nst3d-cli
DATA=../shared/data
for mode in density velocity; do
  ./target/release/nst3d volume \
    --input "$DATA/volumes/smoke_000003.vdb" \
    --style "$DATA/styles/starry_night.jpg" \
    --mode "$mode" \
    --out "out/smoke_000003_$mode.vdb" \
    --preview "out/smoke_000003_$mode.png"
done
echo "previews: out/smoke_000003_density.png out/smoke_000003_velocity.png"
