#!/usr/bin/env bash
# Benchmark: bakes Sponza, Sibenik and the conference room from ../shared/scenes in batch mode
# at the paper's settings (scenes/batch_paper.toml) and writes docs/batch_paper.md: the batch
# summary, then each scene's Table-1 row beside the paper's Sponza row, with the date and the
# machine. About 10 minutes on 2 vCPUs.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${OUT_DIR:-target/batch_paper}"
cargo build --release -p mlt-bake --quiet
report=docs/batch_paper.md
{
    echo "# Batch bake of the paper's scenes"
    echo
    echo "Command: \`scripts/bench_batch.sh\` (\`bake batch scenes/batch_paper.toml --out-dir $out --force --record-timings\`)."
    echo
    echo '```'
    bash scripts/machine.sh
    echo '```'
    echo
    ./target/release/bake batch scenes/batch_paper.toml --out-dir "$out" --force --record-timings -q | sed 's/^# Batch summary/## Batch summary/'
    echo
    echo "## Table 1: each scene beside the paper's Sponza row"
    for s in sponza sibenik conference; do
        echo
        echo "### $s"
        echo
        echo '```'
        ./target/release/bake stats "$out/$s.json" --against paper:sponza
        echo '```'
    done
} > "$report.tmp"
mv "$report.tmp" "$report"
cat "$report"
