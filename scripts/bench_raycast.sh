#!/usr/bin/env bash
# Benchmark: BVH build time and rays/s (closest hit, occlusion), single and all threads,
# on Sponza and the conference room from ../shared/scenes.
set -euo pipefail
cd "$(dirname "$0")/.."
shared="${MLT_SHARED:-../shared}"
cargo build --release -p mlt-scenes --example raycast_bench --quiet
./target/release/examples/raycast_bench "$shared/scenes/sponza_dabrovic/sponza.obj" --viewpoint 0,4,0
./target/release/examples/raycast_bench "$shared/scenes/conference/conference.obj" --viewpoint 1200,400,-150
