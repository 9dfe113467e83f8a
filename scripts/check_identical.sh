#!/usr/bin/env bash
# Fingerprints what a user sees, so that a refactoring can be checked to change none of it:
# bakes of small built-in scenes (with 1 and 2 threads, and a sharded bake merged) and headless
# images of one of them, hashed. Run it before and after a change and diff the two outputs:
#
#   bash scripts/check_identical.sh target/debug > before.txt     # at the old commit
#   bash scripts/check_identical.sh target/debug > after.txt      # at the new one
#   diff before.txt after.txt && echo identical
#
# BIN_DIR holds the `bake` and `view` binaries to use (default target/debug, built first with
# `cargo build --workspace --bins`). Headless rendering uses whatever Vulkan adapter is
# present (Mesa's software driver here), so compare fingerprints taken on one machine.
set -euo pipefail
bin="${1:-target/debug}"
bake="$bin/bake"
view="$bin/view"
for b in "$bake" "$view"; do
    [ -x "$b" ] || { echo "check_identical: $b not found (cargo build --workspace --bins)" >&2; exit 1; }
done
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

small=(--receiver-levels 4 --coarse-count 60 --gather-rays 64 -q)
hash() { sha256sum "$1" | cut -d' ' -f1; }

# Bakes: the same file whatever the thread count.
for t in 1 2; do
    "$bake" builtin:cornell -o "$work/cornell-t$t.mlt" "${small[@]}" --threads "$t" >/dev/null
    echo "bake cornell threads=$t $(hash "$work/cornell-t$t.mlt")"
done
"$bake" 'builtin:sphere?albedo=0.5' -o "$work/sphere.mlt" --receiver-levels 3 --coarse-count 24 \
    --sender-levels 2 --bounces 8 --epsilon 0.001 -q --threads 2 >/dev/null
echo "bake sphere $(hash "$work/sphere.mlt")"
"$bake" 'builtin:box?albedo=0.8' -o "$work/box.mlt" --receiver-levels 3 --coarse-count 30 \
    --sender-levels 2 --bounces auto --epsilon 0.001 -q --threads 2 >/dev/null
echo "bake box-auto $(hash "$work/box.mlt")"
"$bake" builtin:cornell -o "$work/cornell-basis.mlt" "${small[@]}" --basis-only >/dev/null
echo "bake cornell basis-only $(hash "$work/cornell-basis.mlt")"
for i in 0 1; do
    "$bake" builtin:cornell --shard "$i/2" -o "$work/shard$i.mlt" "${small[@]}" >/dev/null
done
"$bake" merge "$work/shard0.mlt" "$work/shard1.mlt" --scene builtin:cornell -o "$work/merged.mlt" -q >/dev/null
echo "bake cornell merged-shards $(hash "$work/merged.mlt")"

# Headless images of the Cornell bake: the window's default view and a moved camera and light.
render() {
    local out="$1"; shift
    if "$view" --help 2>/dev/null | grep -qE '^  render( |$)'; then
        "$view" render "$work/cornell-t1.mlt" --out "$out" "$@" >/dev/null
    else
        "$view" "$work/cornell-t1.mlt" --headless --out "$out" "$@" >/dev/null
    fi
}
render "$work/img-default" --width 160 --height 120 --flatten cpu
render "$work/img-moved" --width 128 --height 96 --flatten cpu \
    --camera-pos 0.15,0.35,0.1 --camera-target 0.35,0.1,0.45 --light-pos 0.3,0.45,0.3
for d in img-default img-moved; do
    for f in direct.exr indirect.exr final.exr final.png; do
        echo "image $d/$f $(hash "$work/$d/$f")"
    done
done
