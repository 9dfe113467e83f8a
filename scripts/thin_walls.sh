#!/usr/bin/env bash
# Light and thin walls: bakes the built-in two rooms (`builtin:rooms`: a partition with a
# doorway, the light in the left room 10 cm from it, the camera in the right room) with
# partitions 2 cm, 5 mm and 1 mm thick, and sealed (no doorway); path-traces a reference of each
# once; renders each bake and prints, per variant, the bake time, peak memory and file size, the
# indirect image's relative RMSE and ratio of means against the reference, and the same by
# 16x16-pixel blocks (relative RMSE, the range of the blocks' ratios). For the sealed rooms,
# whose dark room is black in the reference, it prints the largest indirect pixel of the dark
# room against the lit room's mean (rendered from a camera in the lit room).
#
#   scripts/thin_walls.sh [--spp N] [--size WxH] [--bin DIR] [--work DIR] [--bake-args ARGS]
#
# --bake-args passes more options to each bake (e.g. --no-support-clip, to measure the bake
# without the supports' clipping). Defaults: 1,024 reference paths per pixel, 160x90, release
# binaries in target/release, work files under target/thin_walls (references are kept and
# reused for the same size and spp).
set -euo pipefail
cd "$(dirname "$0")/.."
spp=1024
size=160x90
bin=target/release
work=target/thin_walls
bake_args=""
while [ $# -gt 0 ]; do
    case "$1" in
        --spp) spp="$2"; shift 2 ;;
        --size) size="$2"; shift 2 ;;
        --bin) bin="$2"; shift 2 ;;
        --work) work="$2"; shift 2 ;;
        --bake-args) bake_args="$2"; shift 2 ;;
        *) echo "thin_walls: unknown option $1" >&2; exit 2 ;;
    esac
done
w="${size%x*}"
h="${size#*x}"
mkdir -p "$work"
field() { # JSON FILE, python expression over `v`
    python3 -c "import json,sys; v=json.load(open(sys.argv[1])); print($2)" "$1"
}
bake() { # NAME SCENE: bakes into $work/NAME.mlt, prints "seconds peak-MB size-MB"
    local name=$1 scene=$2
    # shellcheck disable=SC2086
    /usr/bin/time -f "%e %M" -o "$work/$name.time" \
        "$bin/bake" "$scene" -o "$work/$name.mlt" --seed 1 -q $bake_args > "$work/$name.bake.log" 2>&1
    read -r secs kb < "$work/$name.time"
    local bytes
    bytes=$(stat -c %s "$work/$name.mlt")
    echo "$secs $((kb / 1024)) $((bytes / 1000000))"
}
reference() { # NAME SCENE
    local ref="$work/ref_${1}_${w}x${h}_${spp}"
    [ -f "$ref/reference_indirect.exr" ] ||
        "$bin/view" reference "$2" --out "$ref" --width "$w" --height "$h" --spp "$spp" > /dev/null
    echo "$ref"
}
printf '%-22s %8s %8s %7s %10s %8s %10s %14s\n' variant bake_s peak_MB file_MB rel_RMSE ratio block_RMSE block_ratios
for variant in 0.02 0.005 0.001; do
    name="rooms_t$variant"
    scene="builtin:rooms?thickness=$variant"
    ref=$(reference "$name" "$scene")
    read -r secs mb size < <(bake "$name" "$scene")
    "$bin/view" render "$work/$name.mlt" --out "$work/d_$name" --width "$w" --height "$h" --spp 16 > /dev/null
    "$bin/view" compare "$ref" "$work/d_$name" --json > "$work/cmp_$name.json"
    j="$work/cmp_$name.json"
    printf '%-22s %8s %8s %7s %10.4f %8.4f %10.4f %7.3f-%.3f\n' "thickness $variant" "$secs" "$mb" "$size" \
        "$(field "$j" "v['indirect']['relative_rmse']")" "$(field "$j" "v['indirect']['ratio_of_means']")" \
        "$(field "$j" "v['indirect_blocks']['relative_rmse']")" \
        "$(field "$j" "v['indirect_blocks']['ratio_min']")" "$(field "$j" "v['indirect_blocks']['ratio_max']")"
done
# Sealed: the dark room's largest indirect pixel against the lit room's mean.
name=rooms_sealed
read -r secs mb size < <(bake "$name" "builtin:rooms?door=0")
"$bin/view" render "$work/$name.mlt" --out "$work/d_$name" --width "$w" --height "$h" --spp 16 > /dev/null
"$bin/view" render "$work/$name.mlt" --out "$work/d_${name}_lit" --width "$w" --height "$h" --spp 16 \
    --camera-pos=-3.6,1.4,2 --camera-target=0,1.2,2 > /dev/null
"$bin/view" compare "$work/d_${name}_lit" "$work/d_$name" --json > "$work/cmp_$name.json"
j="$work/cmp_$name.json"
lit=$(field "$j" "v['indirect']['reference_mean']")
dark=$(field "$j" "v['indirect_blocks']['test_max']")
printf '%-22s %8s %8s %7s   dark room: largest indirect pixel %.3e, %.2e of the lit room'"'"'s mean %.3e\n' \
    sealed "$secs" "$mb" "$size" "$dark" "$(python3 -c "print($dark / $lit)")" "$lit"
