#!/usr/bin/env bash
# The flat basis in each file's view, as issue 13 measures it: for each FILE=WxH, `view flat
# FILE --width W --height H --json` with the flat weights' normal power of each --power (default:
# this build's, then Eq. 8's 2), and one line per run: flat points, coverage (mean, maximum,
# uncovered pixels), pixels darker than a quarter of the exact image and the flat image's
# relative RMSE from the exact per-pixel evaluation of Eq. 6 (BENCHMARKS.md, "Flattening,
# sharpening and view culling"). CPU only; no GPU needed.
#
#   scripts/bench_flat.sh [--bin DIR] [--power P]... FILE=WxH...
#
# --bin: where `view` is (default target/release).
set -euo pipefail
bin=target/release
powers=()
while [[ $# -gt 0 ]]; do
    case "$1" in
        --bin) bin=$2; shift 2 ;;
        --power) powers+=("$2"); shift 2 ;;
        -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
        --*) echo "bench_flat.sh: unknown option $1" >&2; exit 2 ;;
        *) break ;;
    esac
done
if [[ $# -eq 0 ]]; then
    echo "usage: scripts/bench_flat.sh [--bin DIR] [--power P]... FILE=WxH..." >&2
    exit 2
fi
if [[ ${#powers[@]} -eq 0 ]]; then
    powers=(default 2)
fi
"$(dirname "$0")/machine.sh"
for spec in "$@"; do
    file=${spec%=*}
    size=${spec##*=}
    if [[ "$file" == "$spec" || ! "$size" =~ ^[0-9]+x[0-9]+$ ]]; then
        echo "bench_flat.sh: '$spec' is not FILE=WxH" >&2
        exit 2
    fi
    for p in "${powers[@]}"; do
        args=(flat "$file" --width "${size%x*}" --height "${size#*x}" --json)
        [[ "$p" == default ]] || args+=(--flat-normal-power "$p")
        json=$("$bin/view" "${args[@]}") ||
            { echo "bench_flat.sh: view ${args[*]} failed" >&2; exit 1; }
        python3 - "$json" "$(basename "$file")" "$size" <<'EOF'
import json, sys
j = json.loads(sys.argv[1])
print(f"{sys.argv[2]} {sys.argv[3]} power {j['flat_normal_power']:g}: "
      f"{j['flat_points']} of {j['hierarchical_points']} points flat, "
      f"coverage {j['coverage_mean']:.2f} mean / {j['coverage_max']} max, "
      f"{j['uncovered']} uncovered, {j['darker']} darker, "
      f"flat vs exact {100 * j['rel_rmse']:.2f} %")
EOF
    done
done
