#!/usr/bin/env bash
# The refinement policy's ablation: bakes each scene with the default policy and with each rule
# of `RefinePolicy` turned off alone (`bake --refine-off RULE`), renders each bake headless,
# and compares its indirect image with one path-traced reference per scene. Prints, per scene
# and rule: the links of S, the bake's seconds, the indirect relative RMSE and the ratio of
# means against the reference (and the reference's own noise once per scene).
#
#   scripts/ablation.sh [--bin DIR] [--work DIR] [--rules R1,R2,...] [SCENE ...]
#
# SCENE: a built-in scene or manifest. The Cornell boxes (built-in, or a manifest whose name
# starts with cornell) are rendered at 160x120 with 1024 reference paths per pixel, the rest at
# 160x90 with 256, as in the README's results.
# Default scenes: the built-in Cornell box, the bright box, untextured and textured Sponza and
# the conference room (the last three need ../shared/scenes). Default rules: every rule.
# References and bakes are kept under --work (default target/ablation) and reused.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=target/release
work=target/ablation
rules="coarsest-block,level0-finer-links,level1-budget,contact-budget,middle-budget,finer-budget,min-budget-hits,level0-rays,level1-rays,middle-rays"
while [ $# -gt 0 ]; do
    case "$1" in
        --bin) bin="$2"; shift 2 ;;
        --work) work="$2"; shift 2 ;;
        --rules) rules="$2"; shift 2 ;;
        -*) echo "ablation: unknown option $1" >&2; exit 2 ;;
        *) break ;;
    esac
done
scenes=("$@")
if [ ${#scenes[@]} -eq 0 ]; then
    scenes=(builtin:cornell scenes/cornell_bright.toml scenes/sponza_untextured.toml
        scenes/sponza.toml scenes/conference.toml)
fi
bake="$bin/bake"
view="$bin/view"
for b in "$bake" "$view"; do
    [ -x "$b" ] || { echo "ablation: $b not built (cargo build --release)" >&2; exit 1; }
done
command -v jq >/dev/null || { echo "ablation: needs jq (apt install jq)" >&2; exit 1; }
mkdir -p "$work"
IFS=',' read -r -a rule_list <<<"$rules"
printf '%-22s %-20s %12s %9s %9s %9s\n' scene rule-off links bake-s rmse ratio
for scene in "${scenes[@]}"; do
    tag="$(basename "$scene" .toml | tr -c 'a-z0-9\n' '_')"
    case "$tag" in
        builtin_cornell* | cornell*) size=(--width 160 --height 120); spp=1024 ;;
        *) size=(--width 160 --height 90); spp=256 ;;
    esac
    ref="$work/${tag}_reference"
    for rule in none "${rule_list[@]}"; do
        file="$work/${tag}_${rule}.mlt"
        off=()
        [ "$rule" = none ] || off=(--refine-off "$rule")
        if [ ! -f "$file" ]; then
            "$bake" "$scene" -o "$file" "${off[@]}" -q --stats-json "$file.json" >/dev/null 2>>"$work/log"
        fi
        if [ ! -f "$ref/reference_indirect.exr" ]; then
            "$view" reference "$file" --out "$ref" "${size[@]}" --spp "$spp" >/dev/null 2>>"$work/log"
        fi
        out="$work/${tag}_${rule}_render"
        "$view" render "$file" --out "$out" "${size[@]}" --spp 16 >/dev/null 2>>"$work/log"
        read -r rmse ratio noise < <("$view" compare "$ref" "$out" --json |
            jq -r '.indirect | "\(.relative_rmse) \(.ratio_of_means) \(.noise_relative_rmse)"')
        read -r links secs < <(jq -r '"\(.transport.stats.links) \(.timings.total_s)"' "$file.json")
        printf '%-22s %-20s %12s %9.1f %9.4f %9.4f\n' "$tag" "$rule" "$links" "$secs" "$rmse" "$ratio"
    done
    printf '%-22s %-20s %12s %9s %9.4f\n' "$tag" "(reference noise)" "" "" "$noise"
done
