#!/usr/bin/env bash
# The light near a wall: renders baked built-in Cornell boxes with the point light 10 cm, 2 cm,
# 1 cm and 5 mm in front of the back wall (at mid height) and under the ceiling (above the
# room's centre), path-traces a reference for each position once, and prints the indirect
# image's relative RMSE, the reference's noise floor and the ratio of means per file.
#
#   scripts/near_wall.sh [--spp N] [--size WxH] [--bin DIR] [--work DIR] [--render-args ARGS]
#                        FILE.mlt [FILE.mlt ...]
#
# --render-args passes more options to each `view render` (e.g. "--bounce-feedback 0" for the
# relighting without the bounce-light feedback); the references do not depend on them.
# Defaults: 1,024 reference paths per pixel, 160x120, release binaries in target/release, work
# files under target/near_wall (references are kept there and reused for the same size/spp).
set -euo pipefail
cd "$(dirname "$0")/.."
spp=1024
size=160x120
bin=target/release
work=target/near_wall
render_args=""
while [ $# -gt 0 ]; do
    case "$1" in
        --spp) spp="$2"; shift 2 ;;
        --size) size="$2"; shift 2 ;;
        --bin) bin="$2"; shift 2 ;;
        --work) work="$2"; shift 2 ;;
        --render-args) render_args="$2"; shift 2 ;;
        -*) echo "near_wall: unknown option $1" >&2; exit 2 ;;
        *) break ;;
    esac
done
if [ $# -eq 0 ]; then
    echo "usage: scripts/near_wall.sh [--spp N] [--size WxH] [--bin DIR] [--work DIR] [--render-args ARGS] FILE.mlt..." >&2
    exit 2
fi
for f in "$@"; do
    [ -f "$f" ] || { echo "near_wall: $f: no such file" >&2; exit 1; }
done
w="${size%x*}"
h="${size#*x}"
view="$bin/view"
[ -x "$view" ] || { echo "near_wall: $view not built (cargo build --release)" >&2; exit 1; }
command -v jq >/dev/null || { echo "near_wall: needs jq (apt install jq), as scripts/sweep_error.sh does" >&2; exit 1; }
# Back wall at z = 0.5592 m, ceiling at y = 0.5488 m (the built-in box's measurements).
positions=(
    "back 10 cm|0.278,0.274,0.4592"
    "back 2 cm|0.278,0.274,0.5392"
    "back 1 cm|0.278,0.274,0.5492"
    "back 5 mm|0.278,0.274,0.5542"
    "ceiling 10 cm|0.278,0.4488,0.2795"
    "ceiling 2 cm|0.278,0.5288,0.2795"
    "ceiling 1 cm|0.278,0.5388,0.2795"
    "ceiling 5 mm|0.278,0.5438,0.2795"
)
mkdir -p "$work"
printf '%-14s' "light"
for f in "$@"; do printf ' | %-32s' "$(basename "$f"): RMSE / ratio"; done
printf ' | noise\n'
for entry in "${positions[@]}"; do
    name="${entry%%|*}"
    pos="${entry#*|}"
    tag="$(echo "$name" | tr -c 'a-z0-9\n' '_')"
    ref="$work/ref_${tag}_${size}_${spp}"
    if [ ! -f "$ref/reference_indirect.exr" ]; then
        "$view" reference "$1" --out "$ref" --width "$w" --height "$h" --spp "$spp" \
            --light-pos "$pos" >/dev/null 2>>"$work/log"
    fi
    printf '%-14s' "$name"
    noise=""
    for f in "$@"; do
        out="$work/$(basename "$f" .mlt)_$tag"
        # shellcheck disable=SC2086 # the extra options split into words on purpose
        "$view" render "$f" --out "$out" --width "$w" --height "$h" --spp 4 --light-pos "$pos" \
            $render_args >/dev/null 2>>"$work/log"
        read -r rmse ratio noise < <("$view" compare "$ref" "$out" --json |
            jq -r '.indirect | "\(.relative_rmse) \(.ratio_of_means) \(.noise_relative_rmse)"')
        printf ' | %-32s' "$(printf '%.4f / %.4f' "$rmse" "$ratio")"
    done
    printf ' | %.4f\n' "$noise"
done
