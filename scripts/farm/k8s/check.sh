#!/usr/bin/env bash
# Checks the Kubernetes manifests without a cluster (CI runs it): submit.sh --render fills them
# for the built-in Cornell box in 3 shards, the Jobs' fields that the farm relies on are checked
# (indexed completions, per-index retries, node loss not counted, CPU request = threads, the
# volume), and then the pods' own shell commands are run here, one per index with the
# JOB_COMPLETION_INDEX Kubernetes would give, with the volume's mount point a temporary folder:
# the merge of an incomplete set must fail naming the missing shard, the shard resubmitted
# alone (--only) must fill the gap, and the merged file must be byte-identical to a
# one-process bake.
#
#   scripts/farm/k8s/check.sh [--bin DIR]     (DIR holds bake; default target/release, else target/debug)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../../.." && pwd)"
bin=""
[ "${1:-}" = --bin ] && bin="$2"
if [ -z "$bin" ]; then
    bin="$repo/target/release"
    [ -x "$bin/bake" ] || bin="$repo/target/debug"
fi
bake="$(cd "$bin" && pwd)/bake"
[ -x "$bake" ] || { echo "k8s check: no bake in $bin (cargo build first)" >&2; exit 1; }
python3 -c 'import yaml' 2>/dev/null || { echo "k8s check: python3 with yaml is needed (Debian: python3-yaml; scripts/setup.sh installs it)" >&2; exit 1; }
tmp="$(mktemp -d /tmp/mlt-k8s.XXXXXX)"
trap 'rm -rf "$tmp"' EXIT
small=(--receiver-levels 3 --coarse-count 30 --gather-rays 64)
common=(--image registry.example/mlt:1 --pvc farm --shards 3 --threads 2 --bake "$bake" --mount "$tmp")
"$here/submit.sh" "${common[@]}" --render "$tmp/all" builtin:cornell "$tmp/out" "${small[@]}" >/dev/null
"$here/submit.sh" "${common[@]}" --only 1 --render "$tmp/one" builtin:cornell "$tmp/out" "${small[@]}" >/dev/null

# The fields, and each pod's command written out for the run below.
python3 - "$tmp" <<'PY'
import sys, yaml
tmp = sys.argv[1]
def load(p):
    with open(p) as f:
        return yaml.safe_load(f)
def fail(msg):
    sys.exit(f"k8s check: {msg}")
def pod(job):
    spec = job["spec"]["template"]["spec"]
    if spec.get("restartPolicy") != "Never":
        fail("a Job with a podFailurePolicy needs restartPolicy Never")
    (c,) = spec["containers"]
    (v,) = spec["volumes"]
    if v["persistentVolumeClaim"]["claimName"] != "farm" or c["volumeMounts"][0]["mountPath"] != tmp:
        fail("the shared volume is not mounted where --mount says")
    if c["image"] != "registry.example/mlt:1":
        fail("the image is not the one given")
    return c
def disruption_ignored(job):
    rules = job["spec"]["podFailurePolicy"]["rules"]
    return any(r["action"] == "Ignore" and any(p["type"] == "DisruptionTarget" for p in r.get("onPodConditions", [])) for r in rules)
for name, completions, only in (("all", 3, ""), ("one", 1, "1")):
    job = load(f"{tmp}/{name}/shards.yaml")
    s = job["spec"]
    if job["kind"] != "Job" or s["completionMode"] != "Indexed" or s["completions"] != completions:
        fail(f"{name}: not an indexed Job of {completions} completions")
    if s.get("backoffLimitPerIndex", 0) < 1 or not disruption_ignored(job):
        fail(f"{name}: a shard is not retried on its own, or a lost node counts as a failure")
    c = pod(job)
    if str(c["resources"]["requests"]["cpu"]) != "2" or "--threads 2" not in c["args"][0]:
        fail(f"{name}: the CPU request and the threads differ")
    env = {e["name"]: e["value"] for e in c.get("env", [])}
    if env.get("MLT_SHARD_INDEX") != only:
        fail(f"{name}: MLT_SHARD_INDEX is {env.get('MLT_SHARD_INDEX')!r}, not {only!r}")
    with open(f"{tmp}/{name}.sh", "w") as f:
        f.write(c["args"][0])
    merge = load(f"{tmp}/{name}/merge.yaml")
    if merge["spec"]["completions"] != 1 or not disruption_ignored(merge):
        fail(f"{name}: the merge is not one completion retried after node loss")
    with open(f"{tmp}/{name}_merge.sh", "w") as f:
        f.write(pod(merge)["args"][0])
PY

# The pods' commands, as Kubernetes runs them: shards 0 and 2 of the array...
for i in 0 2; do
    env JOB_COMPLETION_INDEX="$i" MLT_SHARD_INDEX= sh -c "$(cat "$tmp/all.sh")" >/dev/null
done
# ...the merge refuses the incomplete set, naming shard 1...
if sh -c "$(cat "$tmp/all_merge.sh")" 2>"$tmp/merge.err"; then
    echo "k8s check: the merge of 2 of 3 shards succeeded" >&2; exit 1
fi
grep -q "shard_1of3.mlt" "$tmp/merge.err" || { echo "k8s check: the merge's error does not name shard 1: $(cat "$tmp/merge.err")" >&2; exit 1; }
# ...shard 1 resubmitted alone (its Job's only index is 0) fills the gap, and the merge then
# gives the one-process bake's bytes.
env JOB_COMPLETION_INDEX=0 MLT_SHARD_INDEX=1 sh -c "$(cat "$tmp/one.sh")" >/dev/null
[ -f "$tmp/out/shard_1of3.mlt" ] || { echo "k8s check: the resubmitted shard wrote no shard_1of3.mlt" >&2; exit 1; }
sh -c "$(cat "$tmp/one_merge.sh")" >/dev/null
"$bake" builtin:cornell -q -o "$tmp/single.mlt" "${small[@]}" >/dev/null
cmp "$tmp/out/cornell.mlt" "$tmp/single.mlt" || { echo "k8s check: the merged file differs from a one-process bake" >&2; exit 1; }
echo "k8s check: manifests as expected; 3 shards run by the pods' commands, one resubmitted alone, merged byte-identical to one process"
