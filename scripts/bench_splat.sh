#!/usr/bin/env bash
# Per-frame cost of relighting and splatting the flat basis on whatever adapter wgpu picks
# (llvmpipe here, a GPU where one is present): for each FILE=WxH, `view render --frames N`
# with flattening on the CPU and then as a GPU compute pass, and one line per run with the
# CPU stages, the GPU passes and the splatted functions (BENCHMARKS.md, "GPU rendering").
#
#   scripts/bench_splat.sh [--bin DIR] [--frames N] --out DIR FILE=WxH...
#
# --bin: where `view` is (default target/release). The images and timings.json of every run
# stay in --out/<file stem>_<W>x<H>_<flatten>/.
set -euo pipefail
bin=target/release
frames=10
out=
while [[ $# -gt 0 ]]; do
    case "$1" in
        --bin) bin=$2; shift 2 ;;
        --frames) frames=$2; shift 2 ;;
        --out) out=$2; shift 2 ;;
        -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
        --*) echo "bench_splat.sh: unknown option $1" >&2; exit 2 ;;
        *) break ;;
    esac
done
if [[ -z "$out" || $# -eq 0 ]]; then
    echo "usage: scripts/bench_splat.sh [--bin DIR] [--frames N] --out DIR FILE=WxH..." >&2
    exit 2
fi
mkdir -p "$out"
"$(dirname "$0")/machine.sh"
for spec in "$@"; do
    file=${spec%=*}
    size=${spec##*=}
    if [[ "$file" == "$spec" || ! "$size" =~ ^[0-9]+x[0-9]+$ ]]; then
        echo "bench_splat.sh: '$spec' is not FILE=WxH" >&2
        exit 2
    fi
    w=${size%x*}
    h=${size#*x}
    stem=$(basename "$file" .mlt)
    for flatten in cpu gpu; do
        dir="$out/${stem}_${size}_${flatten}"
        "$bin/view" render "$file" --out "$dir" --width "$w" --height "$h" \
            --frames "$frames" --flatten "$flatten" >"$dir.log" 2>&1 ||
            { echo "bench_splat.sh: view render failed, see $dir.log" >&2; tail -5 "$dir.log" >&2; exit 1; }
        # python3 rather than jq (which the other scripts use): the GPU machines this runs on
        # have python3 and nothing can be installed there.
        python3 - "$dir/timings.json" "$stem" "$size" "$flatten" <<'EOF'
import json, sys
t = json.load(open(sys.argv[1]))
c, g = t["cpu_median_ms"], t["gpu_median_ms"]
print(f"{sys.argv[2]} {sys.argv[3]} flatten={sys.argv[4]} on {t['adapter']['name']} "
      f"({t['adapter']['device_type']}), {t['frames']} frames, {t['threads']} threads:")
print("  cpu ms: " + " ".join(f"{k} {v:.2f}" for k, v in c.items()))
print("  gpu ms: " + " ".join(f"{k} {v:.2f}" for k, v in g.items()))
print(f"  splatted {t['splatted_points']} of {t['basis_points']} flat functions; "
      f"frame (cpu + gpu) {c['total'] + g['total']:.2f} ms")
EOF
    done
done
