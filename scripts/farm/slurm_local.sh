#!/usr/bin/env bash
# The farm bake on a real scheduler: starts a one-node Slurm cluster on this machine (munged,
# slurmctld and slurmd as root, on the loopback address only, state under a temporary folder),
# bakes through scripts/farm/submit.sh and checks what a farm user relies on:
#
#   1. a built-in scene and a scenes/ manifest, each in 3 shards with the dependent merge, give
#      files byte-identical to a one-process bake;
#   2. a shard cancelled mid-run leaves no file, its merge is cancelled with it, and a merge of
#      the incomplete set names the missing shard in one line (also with RUST_BACKTRACE set);
#      resubmitting that index alone gives the identical file again;
#   3. a running shard requeued (what Slurm does when its node fails) runs again and the merge
#      is still identical.
#
# Every daemon it started is stopped by its process id and the temporary folder removed, also
# when a step fails; it fails if a daemon is left.
#
#   scripts/farm/slurm_local.sh [--bin DIR] [--keep]
#
# --bin: the folder with bake (default: target/release if built, else target/debug);
# --keep: keep the temporary folder (logs, slurm.conf) and say where. Step 1 uses small
# options (3 receiver levels, 30 coarse points, 64 gather rays) so that a debug build runs it
# in a few minutes; steps 2 and 3 the default bake of the Cornell box (a shard must run long
# enough to be caught mid-run). Installs slurm-wlm and munge from Debian's packages if missing (needs root
# or sudo). Ports: 16817 and 16818 on 127.0.0.1 (MLT_SLURM_PORT sets the first).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
bin=""
keep=0
while [ $# -gt 0 ]; do
    case "$1" in
        --bin) bin="$2"; shift 2 ;;
        --keep) keep=1; shift ;;
        *) echo "slurm_local: unknown argument $1" >&2; exit 2 ;;
    esac
done
if [ -z "$bin" ]; then
    bin="$repo/target/release"
    [ -x "$bin/bake" ] || bin="$repo/target/debug"
fi
bake="$(cd "$bin" && pwd)/bake"
[ -x "$bake" ] || { echo "slurm_local: $bake not built (cargo build -p mlt-bake)" >&2; exit 1; }
small=(--receiver-levels 3 --coarse-count 30 --gather-rays 64)
# The fault cases need shards that run long enough to be caught mid-run: the default bake.
full=()
manifest="$repo/scenes/cornell_obj.toml"

sudo_cmd=()
[ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
need=()
for cmd in slurmctld slurmd munged sbatch; do
    command -v "$cmd" >/dev/null || need=(slurm-wlm munge)
done
if [ ${#need[@]} -gt 0 ]; then
    echo "slurm_local: installing ${need[*]}" >&2
    "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${need[@]}" >/dev/null \
        || { "${sudo_cmd[@]}" apt-get update -q >/dev/null \
            && "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${need[@]}" >/dev/null; }
fi
if [ "$(id -u)" -ne 0 ]; then
    # The daemons run as root (SlurmdUser=root): the simplest one-node cluster.
    exec "${sudo_cmd[@]}" env PATH="$PATH" "$0" --bin "$bin" $([ "$keep" = 1 ] && echo --keep)
fi

root="$(mktemp -d /tmp/mlt-slurm.XXXXXX)"
chmod 700 "$root"
mkdir -p "$root/munge" "$root/state" "$root/spool" "$root/work"
pid_files=("$root/slurmd.pid" "$root/slurmctld.pid" "$root/munge/munged.pid")
step="starting"
stop_daemons() {
    local left=()
    command -v scancel >/dev/null && [ -f "$root/slurm.conf" ] \
        && SLURM_CONF="$root/slurm.conf" timeout 10 scancel --quiet --user=root 2>/dev/null || true
    for f in "${pid_files[@]}"; do
        [ -f "$f" ] || continue
        local pid
        pid="$(cat "$f")"
        kill "$pid" 2>/dev/null || continue
        for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.2; done
        if kill -0 "$pid" 2>/dev/null; then
            kill -9 "$pid" 2>/dev/null || true
            sleep 0.5
        fi
        kill -0 "$pid" 2>/dev/null && left+=("$(basename "$f" .pid) ($pid)")
    done
    if [ ${#left[@]} -gt 0 ]; then
        echo "slurm_local: FAILED: daemons left running: ${left[*]}" >&2
        return 1
    fi
}
finish() {
    local rc=$?
    trap - EXIT INT TERM
    if [ "$rc" -ne 0 ]; then
        echo "slurm_local: FAILED while $step (exit $rc); the daemons' logs:" >&2
        for log in "$root"/*.log "$root"/munge/*.log; do
            [ -f "$log" ] && { echo "== $log" >&2; tail -n 15 "$log" >&2; }
        done
    fi
    stop_daemons || rc=1
    if [ "$keep" = 1 ]; then
        echo "slurm_local: kept $root" >&2
    else
        rm -rf "$root"
    fi
    exit "$rc"
}
trap finish EXIT
trap 'exit 130' INT TERM

# munge: a fresh key, the socket and every file in the temporary folder.
step="starting munged"
dd if=/dev/urandom of="$root/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$root/munge/munge.key"
socket="$root/munge/munge.socket"
munged --force --key-file="$root/munge/munge.key" --socket="$socket" \
    --pid-file="$root/munge/munged.pid" --log-file="$root/munge/munged.log" \
    --seed-file="$root/munge/munged.seed"

# Slurm: one node, this host's name on 127.0.0.1; the node's line from slurmd -C.
step="starting slurmctld and slurmd"
host="$(hostname -s)"
port="${MLT_SLURM_PORT:-16817}"
node="$(slurmd -C | head -n 1) NodeAddr=127.0.0.1 State=UNKNOWN"
cat >"$root/slurm.conf" <<CONF
ClusterName=mltlocal
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$socket
CredType=cred/munge
StateSaveLocation=$root/state
SlurmdSpoolDir=$root/spool
SlurmctldPidFile=$root/slurmctld.pid
SlurmdPidFile=$root/slurmd.pid
SlurmctldLogFile=$root/slurmctld.log
SlurmdLogFile=$root/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MinJobAge=600
$node
PartitionName=local Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF="$root/slurm.conf"
slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF"
for _ in $(seq 120); do
    state="$(sinfo -h -o %T 2>/dev/null || true)"
    [ "$state" = idle ] && break
    sleep 0.5
done
[ "$state" = idle ] || { echo "slurm_local: the node is '$state', not idle, after 60 s" >&2; exit 1; }
echo "slurm_local: one-node cluster up ($host on 127.0.0.1:$port, $(slurmd -C | head -n 1 | grep -o 'CPUs=[0-9]*'))"

# The state of job ID (or ID_TASK), as scontrol has it.
job_state() { scontrol -o show job "$1" 2>/dev/null | grep -o 'JobState=[A-Z_]*' | head -n 1 | cut -d= -f2; }
# Waits until job ID has left the queue (300 s at most); prints its final state.
wait_job() {
    for _ in $(seq 600); do
        [ -z "$(squeue -h -j "$1" 2>/dev/null)" ] && break
        sleep 0.5
    done
    [ -z "$(squeue -h -j "$1" 2>/dev/null)" ] || { echo "slurm_local: job $1 still queued after 300 s" >&2; exit 1; }
    job_state "$1"
}
# Waits until task ID_TASK runs (120 s at most).
wait_running() {
    for _ in $(seq 240); do
        case "$(job_state "$1")" in
            RUNNING) return 0 ;;
            COMPLETED | FAILED | CANCELLED) echo "slurm_local: task $1 ended before it could be caught running" >&2; exit 1 ;;
        esac
        sleep 0.5
    done
    echo "slurm_local: task $1 did not start within 120 s" >&2
    exit 1
}
# Bakes SCENE in one process into FILE with OPTIONS.
single() { "$bake" "$@" -q >/dev/null; }
# Checks that FILE equals the one-process bake REF.
same() {
    cmp -s "$1" "$2" || { echo "slurm_local: FAILED: $1 differs from the one-process bake $2" >&2; exit 1; }
}

# 1. A built-in scene and a manifest, 3 shards each, against one process.
for scene in builtin:cornell "$manifest"; do
    name="$(basename "${scene#builtin:}" .toml)"
    step="baking $scene on the cluster"
    out="$root/work/$name"
    start=$SECONDS
    read -r array merge < <("$here/submit.sh" --shards 3 --bake "$bake" "$scene" "$out" "${small[@]}")
    state="$(wait_job "$merge")"
    [ "$state" = COMPLETED ] || { echo "slurm_local: FAILED: the merge of $scene is $state; its log:" >&2; cat "$out/logs/merge.log" >&2; exit 1; }
    farm_s=$((SECONDS - start))
    start=$SECONDS
    single "$scene" -o "$root/work/$name.single.mlt" "${small[@]}"
    same "$out/$name.mlt" "$root/work/$name.single.mlt"
    echo "slurm_local: $scene: 3 shards and the merge (jobs $array, $merge) in ${farm_s} s, one process in $((SECONDS - start)) s: identical"
done

# 2. A shard cancelled mid-run, then resubmitted alone.
step="the cancelled shard"
out="$root/work/cancel"
single builtin:cornell -o "$root/work/full.single.mlt" "${full[@]}"
read -r array merge < <("$here/submit.sh" --shards 3 --bake "$bake" builtin:cornell "$out" "${full[@]}")
wait_running "${array}_1"
sleep 1
scancel "${array}_1"
wait_job "$array" >/dev/null
state="$(wait_job "$merge")"
[ "$state" = CANCELLED ] || { echo "slurm_local: FAILED: the merge after a cancelled shard is '$state', not CANCELLED" >&2; exit 1; }
[ ! -e "$out/shard_1of3.mlt" ] || { echo "slurm_local: FAILED: the cancelled shard left $out/shard_1of3.mlt" >&2; exit 1; }
left="$(find "$out" -maxdepth 1 -name '.*.tmp*' | head -n 1)"
[ -z "$left" ] || { echo "slurm_local: FAILED: the cancelled shard left $left" >&2; exit 1; }
# The merge of what is there: one line, naming the missing shard, even with RUST_BACKTRACE.
err="$(RUST_BACKTRACE=1 "$bake" merge "$out/shard_0of3.mlt" "$out/shard_2of3.mlt" --scene builtin:cornell -q \
    -o "$out/incomplete.mlt" 2>&1 >/dev/null)" && { echo "slurm_local: FAILED: an incomplete merge succeeded" >&2; exit 1; }
[ "$(printf '%s\n' "$err" | wc -l)" -eq 1 ] && [[ "$err" == *"1/3"* ]] \
    || { echo "slurm_local: FAILED: the incomplete merge's error is not one line naming shard 1/3:" >&2; echo "$err" >&2; exit 1; }
[ ! -e "$out/incomplete.mlt" ] || { echo "slurm_local: FAILED: the refused merge wrote a file" >&2; exit 1; }
echo "slurm_local: shard 1 cancelled mid-run: no file, merge cancelled; merging the rest says: $err"
read -r array merge < <("$here/submit.sh" --shards 3 --only 1 --bake "$bake" builtin:cornell "$out" "${full[@]}")
state="$(wait_job "$merge")"
[ "$state" = COMPLETED ] || { echo "slurm_local: FAILED: the merge after resubmitting shard 1 is $state" >&2; cat "$out/logs/merge.log" >&2; exit 1; }
same "$out/cornell.mlt" "$root/work/full.single.mlt"
echo "slurm_local: shard 1 resubmitted alone (job $array): identical"

# 3. A running shard requeued, as when its node fails.
step="the requeued shard"
out="$root/work/requeue"
read -r array merge < <("$here/submit.sh" --shards 3 --bake "$bake" builtin:cornell "$out" "${full[@]}")
wait_running "${array}_2"
sleep 1
scontrol requeue "${array}_2"
state="$(wait_job "$merge")"
[ "$state" = COMPLETED ] || { echo "slurm_local: FAILED: the merge after a requeue is $state" >&2; cat "$out/logs/merge.log" >&2; exit 1; }
restarts="$(scontrol -o show job "${array}_2" | grep -o 'Restarts=[0-9]*' | cut -d= -f2)"
[ "${restarts:-0}" -ge 1 ] || { echo "slurm_local: FAILED: shard 2 was not requeued (Restarts=${restarts:-?})" >&2; exit 1; }
same "$out/cornell.mlt" "$root/work/full.single.mlt"
echo "slurm_local: shard 2 requeued mid-run (Restarts=$restarts): identical"

step="stopping the daemons"
echo "slurm_local: all checks passed"
