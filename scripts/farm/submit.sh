#!/usr/bin/env bash
# Submits a sharded bake to Slurm: a job array of N shards and a merge that starts when every
# shard succeeded. Prints the two job ids ("ARRAY_ID MERGE_ID") on stdout.
#
#   scripts/farm/submit.sh [--shards N] [--threads T] [--bake PATH] [--sbatch OPTION]...
#                          SCENE OUT_DIR [BAKE_OPTION ...]
#
# SCENE: a built-in scene (builtin:cornell) or a scene manifest; OUT_DIR: a folder every node
# sees (a shared file system), which gets shard_IofN.mlt, logs/ and the merged OUT_DIR/NAME.mlt
# (NAME: the manifest's file name, or the built-in scene's). --shards: N (default 4);
# --threads: CPUs per shard (default 1; the shard's file does not depend on it); --bake: the
# bake binary as the nodes see it (default: target/release/bake of this checkout); --sbatch:
# passed to both submissions (a partition, an account, --mem, a time limit), repeatable.
# BAKE_OPTIONs (after SCENE and OUT_DIR) go to every shard.
#
# The shards are requeued when their node fails. A shard that fails or is cancelled leaves no
# file and the merge is cancelled with it (--kill-on-invalid-dep): resubmit only that index,
#   scripts/farm/submit.sh --only I ...same arguments...
# which submits shard I alone and a new merge.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
n=4
threads=1
bake="$here/../../target/release/bake"
only=""
sbatch_opts=()
while [ $# -gt 0 ]; do
    case "$1" in
        --shards) n="$2"; shift 2 ;;
        --threads) threads="$2"; shift 2 ;;
        --bake) bake="$2"; shift 2 ;;
        --only) only="$2"; shift 2 ;;
        --sbatch) sbatch_opts+=("$2"); shift 2 ;;
        -h | --help) sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        -*) echo "submit.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
        *) break ;;
    esac
done
[ $# -ge 2 ] || { echo "submit.sh: usage: submit.sh [OPTIONS] SCENE OUT_DIR [BAKE_OPTION ...] (see --help)" >&2; exit 2; }
scene="$1" out="$2"
shift 2
[[ "$n" =~ ^[1-9][0-9]*$ ]] || { echo "submit.sh: --shards must be a positive integer, not '$n'" >&2; exit 2; }
[[ "$threads" =~ ^[1-9][0-9]*$ ]] || { echo "submit.sh: --threads must be a positive integer, not '$threads'" >&2; exit 2; }
if [ -n "$only" ] && ! { [[ "$only" =~ ^[0-9]+$ ]] && [ "$only" -lt "$n" ]; }; then
    echo "submit.sh: --only must be a shard index below $n, not '$only'" >&2
    exit 2
fi
command -v sbatch >/dev/null || { echo "submit.sh: sbatch not found (is this a Slurm submit host?)" >&2; exit 1; }
[ -x "$bake" ] || { echo "submit.sh: $bake is not an executable bake (cargo build --release, or --bake PATH)" >&2; exit 1; }
bake="$(cd "$(dirname "$bake")" && pwd)/$(basename "$bake")"
# A manifest is given to the nodes by its absolute path; a built-in scene as it is.
case "$scene" in
    builtin:*) name="${scene#builtin:}" ;;
    *)
        [ -f "$scene" ] || { echo "submit.sh: scene manifest $scene not found" >&2; exit 1; }
        scene="$(cd "$(dirname "$scene")" && pwd)/$(basename "$scene")"
        name="$(basename "$scene" .toml)"
        ;;
esac
mkdir -p "$out/logs"
out="$(cd "$out" && pwd)"
array="0-$((n - 1))"
[ -z "$only" ] || array="$only"
array_id="$(sbatch --parsable "${sbatch_opts[@]}" --array="$array" --cpus-per-task="$threads" \
    --output="$out/logs/shard_%a.log" "$here/shard.sbatch" "$bake" "$scene" "$n" "$out" "$@")"
array_id="${array_id%%;*}"
merge_id="$(sbatch --parsable "${sbatch_opts[@]}" --dependency="afterok:$array_id" --kill-on-invalid-dep=yes \
    --output="$out/logs/merge.log" "$here/merge.sbatch" "$bake" "$scene" "$n" "$out" "$out/$name.mlt")"
merge_id="${merge_id%%;*}"
echo "$array_id $merge_id"
