#!/usr/bin/env bash
# The frame with the relighting on the CPU and on the GPU, one prepared run for a GPU host
# (the `device` tool): builds, bakes the built-in Cornell box and textured Sponza, then for
# each at each size renders `view render --frames N` with `--relight cpu`, `--relight gpu` and
# `--relight gpu --splat-bits 16`, and prints per-stage medians (the relighting's stages, the
# GPU passes, the frame) and how far each image is from the CPU path's (`view compare`).
# About 6 minutes on a 16-core GPU host with a warm cargo cache; less with SIZES or SCENES.
#
#   scripts/bench_gpu.sh [--frames N] [--out DIR]
#
# Environment: SIZES (default "640x360 1280x720 1920x1080"), SCENES (default
# "builtin:cornell scenes/sponza.toml"), MLT_SKIP_BUILD=1 to use target/release as it is.
# Output: one block per run on stdout; images and timings.json under DIR (default
# target/bench_gpu).
set -euo pipefail
cd "$(dirname "$0")/.."
frames=20
out=target/bench_gpu
while [[ $# -gt 0 ]]; do
    case "$1" in
        --frames) frames=$2; shift 2 ;;
        --out) out=$2; shift 2 ;;
        -h|--help) sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "bench_gpu.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done
sizes=${SIZES:-640x360 1280x720 1920x1080}
scenes=${SCENES:-builtin:cornell scenes/sponza.toml}
[[ "${MLT_SKIP_BUILD:-0}" == 1 ]] || cargo build --release --locked --bins -q
bin=target/release
mkdir -p "$out"
bash scripts/machine.sh
for scene in $scenes; do
    case "$scene" in builtin:*) stem=${scene#builtin:} ;; *) stem=$(basename "$scene" .toml) ;; esac
    file="$out/$stem.mlt"
    [[ -f "$file" ]] || { echo "baking $scene"; "$bin/bake" "$scene" -q -o "$file" >/dev/null; }
    for size in $sizes; do
        w=${size%x*}
        h=${size#*x}
        for run in cpu gpu gpu16; do
            dir="$out/${stem}_${size}_${run}"
            opts=(--relight "${run%16}")
            [[ "$run" == gpu16 ]] && opts+=(--splat-bits 16)
            "$bin/view" render "$file" --out "$dir" --width "$w" --height "$h" --frames "$frames" \
                "${opts[@]}" >"$dir.log" 2>&1 ||
                { echo "bench_gpu.sh: view render failed, see $dir.log" >&2; tail -5 "$dir.log" >&2; exit 1; }
            diff=""
            if [[ "$run" != cpu ]]; then
                diff=$("$bin/view" compare "$out/${stem}_${size}_cpu" "$dir" --json 2>/dev/null |
                    python3 -c 'import json,sys; r=json.load(sys.stdin); print("indirect %.4f / final %.4f rel. RMSE" % (r["indirect"]["relative_rmse"], r["final_image"]["relative_rmse"]))' || true)
            fi
            # python3 rather than jq: the GPU hosts have python3 and nothing can be installed there.
            python3 - "$dir/timings.json" "$stem" "$size" "$run" "$diff" <<'PY'
import json, sys
t = json.load(open(sys.argv[1]))
c, g = t["cpu_median_ms"], t["gpu_median_ms"]
print(f"{sys.argv[2]} {sys.argv[3]} {sys.argv[4]} on {t['adapter']['name']} ({t['adapter']['device_type']}), "
      f"{t['frames']} frames, {t['threads']} threads, accumulation {t['accumulation_format']}:")
print(f"  relighting ({t['relight']}) ms: " + " ".join(f"{k} {v:.2f}" for k, v in c.items()))
print("  gpu passes ms: " + " ".join(f"{k} {v:.2f}" for k, v in g.items()))
print(f"  frame {c['total'] + g['total']:.2f} ms (stages one after the other)"
      + (f"; against --relight cpu: {sys.argv[5]}" if sys.argv[5] else ""))
PY
        done
    done
done
