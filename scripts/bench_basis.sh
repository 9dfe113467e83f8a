#!/usr/bin/env bash
# Benchmark: basis construction only (candidates, Poisson disk, R-trees; --basis-only) on a
# scene manifest.
# Usage: scripts/bench_basis.sh [MANIFEST] [extra bake flags...]
# Default: scenes/sponza.toml (the paper's Sponza: 6 levels, about 339 level-0 points).
set -euo pipefail
cd "$(dirname "$0")/.."
manifest="${1:-scenes/sponza.toml}"
shift || true
bash scripts/machine.sh
cargo build --release -p mlt-bake --quiet
out="${TMPDIR:-/tmp}/bench_basis.mlt"
for threads in 1 "$(nproc)"; do
    echo "== $manifest, $threads thread(s)"
    ./target/release/bake "$manifest" -o "$out" --basis-only --preset paper --threads "$threads" --stats-json "$out.json" "$@"
done
ls -l "$out"
