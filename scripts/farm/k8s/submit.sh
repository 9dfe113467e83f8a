#!/usr/bin/env bash
# Submits a sharded bake to Kubernetes: the shards as an indexed Job (shards.yaml), then, once
# every index completed, the merge (merge.yaml). Both manifests are templates filled here.
# Written for clusters with Kubernetes 1.29 or later (backoffLimitPerIndex); not run on one (none
# was reachable where it was written): --render, which CI checks (check.sh), writes the filled
# manifests without applying them.
#
#   scripts/farm/k8s/submit.sh --image IMAGE --pvc CLAIM [--shards N] [--threads T]
#       [--parallelism P] [--memory M] [--merge-memory M] [--mount PATH] [--bake PATH]
#       [--name NAME] [--only I] [--timeout SECONDS] [--render DIR]
#       SCENE OUT_DIR [BAKE_OPTION ...]
#
# SCENE and OUT_DIR are paths as the pods see them, on the volume CLAIM (ReadWriteMany) mounted
# at --mount (default /farm), or a built-in scene (builtin:cornell); no spaces in them. IMAGE
# holds the bake binary (--bake, default `bake` on its PATH). --shards N (default 4), --threads
# T per shard (default 1, the pod's CPU request), --parallelism P pods at once (default N),
# --memory per shard pod (default 2Gi; docs/farm.md gives the measured peaks), --merge-memory
# (default 4Gi). --name: the Jobs' prefix (default: the scene's name, lower case). --only I
# resubmits shard I alone and then the merge. --timeout: how long to wait for each Job (default
# 86400 s); a Job that fails ends the wait at once, with the failed shard indexes. BAKE_OPTIONs go to every shard and must be the same for every shard of one bake.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
n=4 threads=1 parallelism="" memory=2Gi merge_memory=4Gi mount=/farm bake=bake name="" only=""
image="" pvc="" timeout=86400 render=""
while [ $# -gt 0 ]; do
    case "$1" in
        --shards) n="$2"; shift 2 ;;
        --threads) threads="$2"; shift 2 ;;
        --parallelism) parallelism="$2"; shift 2 ;;
        --memory) memory="$2"; shift 2 ;;
        --merge-memory) merge_memory="$2"; shift 2 ;;
        --mount) mount="$2"; shift 2 ;;
        --bake) bake="$2"; shift 2 ;;
        --name) name="$2"; shift 2 ;;
        --only) only="$2"; shift 2 ;;
        --image) image="$2"; shift 2 ;;
        --pvc) pvc="$2"; shift 2 ;;
        --timeout) timeout="$2"; shift 2 ;;
        --render) render="$2"; shift 2 ;;
        -h | --help) sed -n '2,21p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        -*) echo "k8s/submit.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
        *) break ;;
    esac
done
[ $# -ge 2 ] || { echo "k8s/submit.sh: usage: submit.sh --image IMAGE --pvc CLAIM [OPTIONS] SCENE OUT_DIR [BAKE_OPTION ...] (see --help)" >&2; exit 2; }
scene="$1" out="$2"
shift 2
[ -n "$image" ] || { echo "k8s/submit.sh: --image is required (an image with the bake binary)" >&2; exit 2; }
[ -n "$pvc" ] || { echo "k8s/submit.sh: --pvc is required (a ReadWriteMany claim every pod mounts)" >&2; exit 2; }
for v in n threads timeout; do
    [[ "${!v}" =~ ^[1-9][0-9]*$ ]] || { echo "k8s/submit.sh: --$( [ "$v" = n ] && echo shards || echo "$v") must be a positive integer, not '${!v}'" >&2; exit 2; }
done
parallelism="${parallelism:-$n}"
[[ "$parallelism" =~ ^[1-9][0-9]*$ ]] || { echo "k8s/submit.sh: --parallelism must be a positive integer, not '$parallelism'" >&2; exit 2; }
if [ -n "$only" ] && ! { [[ "$only" =~ ^[0-9]+$ ]] && [ "$only" -lt "$n" ]; }; then
    echo "k8s/submit.sh: --only must be a shard index below $n, not '$only'" >&2
    exit 2
fi
for p in "$scene" "$out" "$mount"; do
    case "$p" in *[[:space:]]*) echo "k8s/submit.sh: '$p' has a space; the pods' shell commands do not quote it" >&2; exit 2 ;; esac
done
case "$scene" in
    builtin:*) base="${scene#builtin:}" ;;
    *) base="$(basename "$scene" .toml)" ;;
esac
# A Job name is a DNS label: lower case, digits and '-', at most 63 characters with "-shard-I".
name="${name:-$(printf '%s' "$base" | tr 'A-Z_.' 'a-z--' | tr -cd 'a-z0-9-')}"
[[ "$name" =~ ^[a-z0-9]([a-z0-9-]{0,40}[a-z0-9])?$ ]] || { echo "k8s/submit.sh: '$name' is not a usable Job name (lower case, digits, '-'; --name)" >&2; exit 2; }
command -v envsubst >/dev/null || { echo "k8s/submit.sh: envsubst not found (Debian: gettext-base)" >&2; exit 1; }

export NAME="$name" SHARDS="$n" THREADS="$threads" MEMORY="$memory" MERGE_MEMORY="$merge_memory"
export MOUNT="$mount" BAKE="$bake" IMAGE="$image" PVC="$pvc" SCENE="$scene" OUT_DIR="$out"
export OUTPUT="$out/$base.mlt" BAKE_OPTIONS="$*" ONLY="$only"
if [ -n "$only" ]; then
    export JOB_NAME="$name-shard-$only" COMPLETIONS=1 PARALLELISM=1
else
    export JOB_NAME="$name-shards" COMPLETIONS="$n" PARALLELISM="$parallelism"
fi
# Only these are filled: the pods' own shell variables ($i, $JOB_COMPLETION_INDEX) stay.
fields='${NAME} ${JOB_NAME} ${SHARDS} ${COMPLETIONS} ${PARALLELISM} ${THREADS} ${MEMORY} ${MERGE_MEMORY} ${MOUNT} ${BAKE} ${IMAGE} ${PVC} ${SCENE} ${OUT_DIR} ${OUTPUT} ${BAKE_OPTIONS} ${ONLY}'
fill() { envsubst "$fields" < "$here/$1"; }

if [ -n "$render" ]; then
    mkdir -p "$render"
    fill shards.yaml > "$render/shards.yaml"
    fill merge.yaml > "$render/merge.yaml"
    echo "$render/shards.yaml $render/merge.yaml"
    exit 0
fi
command -v kubectl >/dev/null || { echo "k8s/submit.sh: kubectl not found" >&2; exit 1; }
# Waits for job $1 to be Complete (0) or Failed (1, or on the timeout), polling its conditions.
wait_job() {
    local end=$((SECONDS + timeout)) c
    while [ "$SECONDS" -lt "$end" ]; do
        c=" $(kubectl get job "$1" -o jsonpath='{range .status.conditions[?(@.status=="True")]}{.type} {end}') "
        case "$c" in
            *" Complete "*) return 0 ;;
            *" Failed "*) return 1 ;;
        esac
        sleep 10
    done
    echo "k8s/submit.sh: job/$1 still running after $timeout s" >&2
    return 1
}
# A finished Job of the same name would make apply fail (its pod template is immutable).
kubectl delete job "$JOB_NAME" "$name-merge" --ignore-not-found >/dev/null
fill shards.yaml | kubectl apply -f -
echo "waiting for job/$JOB_NAME ($COMPLETIONS of $n shards)" >&2
if ! wait_job "$JOB_NAME"; then
    failed="$(kubectl get job "$JOB_NAME" -o jsonpath='{.status.failedIndexes}' 2>/dev/null || true)"
    echo "k8s/submit.sh: error: job/$JOB_NAME did not complete${failed:+; failed shard indexes: $failed (resubmit each with --only I)}" >&2
    exit 1
fi
fill merge.yaml | kubectl apply -f -
wait_job "$name-merge" \
    || { echo "k8s/submit.sh: error: job/$name-merge did not complete (kubectl logs job/$name-merge)" >&2; exit 1; }
echo "$OUTPUT"
