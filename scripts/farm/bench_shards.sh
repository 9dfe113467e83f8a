#!/usr/bin/env bash
# What one shard of a sharded bake costs, for sizing a farm: bakes each of N shards of SCENE in
# turn (as N nodes would in parallel) with T threads, then merges them, and prints per shard its
# wall time, CPU time, peak memory (max RSS) and file size, and the same for the merge and for
# a one-process bake of the whole scene. The merged file is checked byte-identical to the
# one-process bake.
#
#   scripts/farm/bench_shards.sh SCENE [N [T]]     (N default 4, T default 1; release build)
#
# Output: a Markdown table on stdout; the files under target/bench_shards/NAME_N.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
bake="$repo/target/release/bake"
[ -x "$bake" ] || { echo "bench_shards: build first: cargo build --release --locked --bins" >&2; exit 1; }
[ -x /usr/bin/time ] || { echo "bench_shards: /usr/bin/time is needed (Debian: time)" >&2; exit 1; }
[ $# -ge 1 ] || { echo "bench_shards: usage: bench_shards.sh SCENE [N [T]]" >&2; exit 2; }
scene="$1" n="${2:-4}" t="${3:-1}"
case "$scene" in builtin:*) name="${scene#builtin:}" ;; *) name="$(basename "$scene" .toml)" ;; esac
out="$repo/target/bench_shards/${name}_$n"
rm -rf "$out"
mkdir -p "$out"
bash "$repo/scripts/machine.sh"
echo "scene: $scene, $n shards, $t threads each"
echo
echo "| run | wall | CPU (user+sys) | peak memory | file |"
echo "|---|---:|---:|---:|---:|"
# Runs "$@" under /usr/bin/time and prints one table row; $1 is the row's name, $2 the file.
row() {
    local label="$1" file="$2"
    shift 2
    /usr/bin/time -f '%e %U %S %M' -o "$out/time" "$@"
    read -r wall user sys rss < "$out/time"
    awk -v l="$label" -v w="$wall" -v u="$user" -v s="$sys" -v r="$rss" -v b="$(stat -c %s "$file")" \
        'BEGIN { printf "| %s | %.1f s | %.1f s | %.0f MB | %.1f MB |\n", l, w, u + s, r / 1024, b / 1e6 }'
}
files=()
for ((i = 0; i < n; i++)); do
    f="$out/shard_${i}of${n}.mlt"
    row "shard $i/$n" "$f" "$bake" "$scene" --shard "$i/$n" --threads "$t" -q -o "$f"
    files+=("$f")
done
row "merge" "$out/$name.mlt" env RAYON_NUM_THREADS="$t" "$bake" merge "${files[@]}" --scene "$scene" -q -o "$out/$name.mlt"
row "one process" "$out/single.mlt" "$bake" "$scene" --threads "$t" -q -o "$out/single.mlt"
cmp -s "$out/$name.mlt" "$out/single.mlt" && echo && echo "merged file byte-identical to the one-process bake" \
    || { echo "bench_shards: the merged file differs from the one-process bake" >&2; exit 1; }
