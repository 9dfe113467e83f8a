#!/usr/bin/env bash
# A longer run of the fuzz harness (tests/tests/fuzz_inputs.rs) over the baked-file reader, the
# OBJ+MTL loader, the glTF loader and the manifest parser: COUNT mutated inputs per target
# (split between a target's variants), from SEED. `cargo test` runs the same harness with a
# few thousand inputs per target.
#
#   bash scripts/fuzz.sh [COUNT] [SEED]      # default 50000 inputs per target, seed 1
#
# Prints one line per target (inputs tried, failures, slowest input, largest allocation);
# failing inputs are saved in $MLT_FUZZ_OUT (default target/fuzz-failures) for replay. Exits
# non-zero when any input panicked, ran past the time limit or allocated past the cap.
set -euo pipefail
count="${1:-50000}"
seed="${2:-1}"
out="${MLT_FUZZ_OUT:-target/fuzz-failures}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
MLT_FUZZ_COUNT="$count" MLT_FUZZ_SEED="$seed" MLT_FUZZ_OUT="$out" RUST_BACKTRACE=0 \
    cargo test -p mlt-tests --test fuzz_inputs -- --nocapture --test-threads 1 2>&1 |
    grep --line-buffered -E '^fuzz |^test |input [0-9]+:|^test result'
