#!/usr/bin/env bash
# Stylizes the bundled example (a real smoke frame from ../shared/data) with
# Van Gogh's Starry Night, in both modes by optimisation and once by the
# example feed-forward model. Outputs land in out/.
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
# The same frame through the example feed-forward model (trained by
# tools/train_example.sh on plume48, which never saw this frame): one pass,
# every viewpoint at once, in seconds.
./target/release/nst3d volume \
  --model models/starry_density.safetensors \
  --input "$DATA/volumes/smoke_000003.vdb" \
  --out out/smoke_000003_feedforward.vdb
./target/release/nst3d preview \
  --input "$DATA/volumes/smoke_000003.vdb" --compare out/smoke_000003_feedforward.vdb \
  --turntable 4 --elevation 30 --out "out/smoke_000003_feedforward_####.png"
echo "previews: out/smoke_000003_density.png out/smoke_000003_velocity.png out/smoke_000003_feedforward_0001..4.png"
