#!/usr/bin/env bash
# How the bake's cost grows (issue 14): bake time per phase, peak memory and file size against
# the triangle count at fixed geometry (Sponza with every triangle split into 4 and 16 by
# `[scene] subdivide`, at 5 and at 6 receiver levels), against the receiver levels (Sponza at 4
# to 7), and for the conference room at 6 levels. Default preset (converged bounces), all
# threads, one bake at a time.
#
# Usage: scripts/bench_scaling.sh
# Environment (defaults in brackets):
#   CASES  the cases to bake, in order [sponza_l4 sponza_l5 sponza_x4_l5 sponza_x16_l5 sponza_l6
#          sponza_x16 conference_l6 sponza_x4 sponza_l7: the cheap ones first]. A case is
#          SCENE[_xK][_lN]: scenes/SCENE.toml with every triangle split into K = 4^s
#          (subdivide = s) at N receiver levels [6], e.g. cornell_l3, cornell_x4_l3. A case whose statistics exist in WORK is not baked again (delete
#          WORK/CASE.json to redo it); the table and the plot hold every case found in WORK.
#   BIN    directory of the release `bake` [target/release]
#   PLOT   the plot_scaling binary [target/release/plot_scaling, else target/debug/plot_scaling]
#   WORK   scratch directory: generated manifests, files, statistics, logs [target/scaling]
#   OUT    output prefix: OUT.csv, OUT.md, OUT.png [docs/scaling]
#   ARGS   extra bake arguments for every case (e.g. "--threads 1") [none]
#   KEEP   1 keeps the baked .mlt files in WORK [0: deleted once measured]
#   MLT_SHARED  the third-party scenes' root, for manifests that name ../../shared [../shared]
# Build first: cargo build --release -p mlt-bake -p mlt-plot
# Peak memory is the process's maximum resident set (/usr/bin/time -v), which also covers
# writing the file; the bake's own figure (stats JSON, at the end of the transport) is in the CSV.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
BIN=${BIN:-$ROOT/target/release}
WORK=${WORK:-$ROOT/target/scaling}
OUT=${OUT:-$ROOT/docs/scaling}
ARGS=${ARGS:-}
KEEP=${KEEP:-0}
SHARED=${MLT_SHARED:-$ROOT/../shared}
# The table's order: the receiver levels, then the triangles.
ALL_CASES="sponza_l4 sponza_l5 sponza_l6 sponza_l7 sponza_x4_l5 sponza_x16_l5 sponza_x4 sponza_x16 conference_l6"
CASES=${CASES:-sponza_l4 sponza_l5 sponza_x4_l5 sponza_x16_l5 sponza_l6 sponza_x16 conference_l6 sponza_x4 sponza_l7}
if [[ -z ${PLOT:-} ]]; then
  PLOT=$ROOT/target/release/plot_scaling
  [[ -x $PLOT ]] || PLOT=$ROOT/target/debug/plot_scaling
fi
[[ -d $SHARED/scenes ]] || { echo "no $SHARED/scenes: set MLT_SHARED" >&2; exit 1; }
[[ -x $BIN/bake ]] || { echo "missing $BIN/bake: cargo build --release -p mlt-bake" >&2; exit 1; }
[[ -x /usr/bin/time ]] || { echo "needs GNU time (/usr/bin/time -v) for peak memory" >&2; exit 1; }
command -v jq >/dev/null || { echo "needs jq" >&2; exit 1; }
mkdir -p "$WORK" "$(dirname "$OUT")"
MACHINE=$("$ROOT/scripts/machine.sh")
echo "$MACHINE" >&2

# Splits a case name into SCENE, SUBDIVIDE (levels of 1-to-4 splits) and LEVELS.
parse_case() {
  local c=$1
  SCENE=${c%%_*}
  SUBDIVIDE=0
  LEVELS=6
  local part
  for part in $(tr '_' ' ' <<<"${c#"$SCENE"}"); do
    case $part in
      l[0-9]*) LEVELS=${part#l} ;;
      x[0-9]*)
        local k=${part#x} s=0 n=1
        while ((n < k)); do n=$((n * 4)); s=$((s + 1)); done
        ((n == k)) || { echo "$c: x$k is not a power of 4" >&2; return 1; }
        SUBDIVIDE=$s ;;
      *) echo "$c: unknown part '$part' (expected xK or lN)" >&2; return 1 ;;
    esac
  done
  [[ -f $ROOT/scenes/$SCENE.toml ]] || { echo "$c: no scenes/$SCENE.toml" >&2; return 1; }
}

# The manifest a case bakes: a copy of the scene's in WORK, its mesh path made absolute (the
# third-party scenes from SHARED, the others from scenes/) and, when asked, `subdivide` added
# to `[scene]`.
manifest_for() {
  local m=$WORK/${SCENE}_subdivide$SUBDIVIDE.toml
  local add=""
  ((SUBDIVIDE == 0)) || add="\nsubdivide = $SUBDIVIDE"
  sed -e "s|^\[scene\]|[scene]$add|" \
      -e "s|^source = \"\.\./\.\./shared/|source = \"$SHARED/|" \
      -e "/^source = \"builtin:/!s|^source = \"\([^/][^\"]*\)\"|source = \"$ROOT/scenes/\1\"|" \
      "$ROOT/scenes/$SCENE.toml" >"$m"
  echo "$m"
}

# On each new line of the bake's log (one per stage), the process's CPU time so far (user +
# system, in clock ticks) and the line: the phases' CPU times, which the wall-clock times the
# bake reports do not give on a loaded machine. Polled twice a second.
monitor() {
  local pid=$1 log=$2 out=$3 seen=0 n cpu stat
  : >"$out"
  while [[ -r /proc/$pid/stat ]]; do
    read -r -a stat <"/proc/$pid/stat" || break
    cpu=$((stat[13] + stat[14]))
    n=$(wc -l <"$log")
    if ((n > seen)); then
      tail -n +$((seen + 1)) "$log" | head -n $((n - seen)) | sed "s|^|$cpu\t|" >>"$out"
      seen=$n
    fi
    sleep 0.5
  done
}

# CPU seconds of a phase from CASE.cpu: the ticks at the line matching $3 less those at $2.
phase_cpu() {
  [[ -s $1 ]] || { echo ""; return; }
  awk -F'\t' -v a="$2" -v b="$3" -v tck="$(getconf CLK_TCK)" '
    $2 ~ a && ta == "" { ta = $1 } $2 ~ b && tb == "" { tb = $1 }
    END { if (ta != "" && tb != "") printf "%.2f", (tb - ta) / tck }' "$1"
}

# 1. The bakes.
for c in $CASES; do
  parse_case "$c"
  if [[ -s $WORK/$c.json && -s $WORK/$c.time ]]; then
    echo "== $c: done before (delete $WORK/$c.json to redo)" >&2
    continue
  fi
  manifest=$(manifest_for)
  echo "== $c: $BIN/bake $manifest --receiver-levels $LEVELS $ARGS ($(date -u +%H:%M:%S))" >&2
  rm -f "$WORK/$c.json" "$WORK/$c.time" "$WORK/$c.cpu"
  : >"$WORK/$c.log"
  # shellcheck disable=SC2086
  /usr/bin/time -v -o "$WORK/$c.time.tmp" "$BIN/bake" "$manifest" --receiver-levels "$LEVELS" \
    -o "$WORK/$c.mlt" --stats-json "$WORK/$c.json" $ARGS >"$WORK/$c.log" 2>&1 &
  timer=$!
  sleep 0.2
  bake_pid=$(pgrep -P "$timer" || true)
  [[ -z $bake_pid ]] || monitor "$bake_pid" "$WORK/$c.log" "$WORK/$c.cpu" &
  wait "$timer" || { echo "$c failed: see $WORK/$c.log" >&2; tail -5 "$WORK/$c.log" >&2; exit 1; }
  wait
  # The lines written after the last poll ended before the exit: the process's total CPU.
  ticks=$(awk -F': ' -v tck="$(getconf CLK_TCK)" '/User time/{u=$2} /System time/{s=$2}
                      END{printf "%d", (u + s) * tck}' "$WORK/$c.time.tmp")
  tail -n +$(($(wc -l <"$WORK/$c.cpu") + 1)) "$WORK/$c.log" | sed "s|^|$ticks\t|" >>"$WORK/$c.cpu"
  mv "$WORK/$c.time.tmp" "$WORK/$c.time"
  echo "$BIN/bake ($("$BIN/bake" --version))" >"$WORK/$c.bin"
  ((KEEP == 1)) || rm -f "$WORK/$c.mlt"
  grep -E 'Elapsed|Maximum resident' "$WORK/$c.time" >&2
done

# 2. The CSV: every case found in WORK, in the order of the full set, then any others.
csv=$OUT.csv
found=$(for c in $ALL_CASES; do echo "$c"; done
        for f in "$WORK"/*.json; do [[ -e $f ]] && basename "$f" .json; done)
echo "case,scene,subdivide,triangles,levels,points,links,gather_rays,bounces,load_s,placement_s,refine_s,bounces_s,write_s,total_s,wall_s,cpu_s,placement_cpu_s,refine_cpu_s,bounces_cpu_s,receivers_refined,refine_cpu_ms_per_receiver,peak_mb,bake_peak_mb,file_mb,threads" >"$csv"
seen=" "
for c in $found; do
  [[ $seen == *" $c "* ]] && continue
  seen="$seen$c "
  j=$WORK/$c.json t=$WORK/$c.time
  [[ -s $j && -s $t ]] || continue
  parse_case "$c"
  wall=$(awk -F': ' '/Elapsed \(wall clock\)/{n=split($2,a,":"); s=0; for(i=1;i<=n;i++) s=s*60+a[i]; print s}' "$t")
  cpu=$(awk -F': ' '/User time/{u=$2} /System time/{s=$2} END{print u+s}' "$t")
  rss=$(awk -F': ' '/Maximum resident set size/{printf "%.1f", $2/1000}' "$t")
  k=$WORK/$c.cpu
  phases="$(phase_cpu "$k" 'ray-casting structure' 'r-trees:'),$(phase_cpu "$k" 'r-trees:' 'refinement of T:'),$(phase_cpu "$k" 'refinement of T:' 'indirect bounces:')"
  jq -r --arg c "$c" --arg scene "$SCENE" --arg sub "$SUBDIVIDE" --arg wall "$wall" \
     --arg cpu "$cpu" --arg rss "$rss" --arg phases "$phases" '
    def r(n): . * pow(10; n) | round / pow(10; n);
    [$c, $scene, $sub, .meta.scene.triangles, .transport.params.receiver_levels,
     .meta.stats.points, .transport.stats.links, .transport.stats.visibility_rays,
     .transport.stats.bounces,
     (.timings.load_s + .timings.bvh_s | r(2)),
     (.timings.candidates_s + .timings.poisson_s + .timings.rtrees_s | r(2)),
     (.transport.timings.refine_s | r(2)), (.transport.timings.bounces_s | r(2)),
     (.timings.write_s | r(2)), (.timings.total_s | r(2)), ($wall | tonumber | r(2)),
     ($cpu | tonumber | r(2)), $phases,
     (.transport.stats.receivers_refined | add) as $n | $n,
     ($phases | split(",")[1] | if . == "" then "" else tonumber * 1000 / $n | r(3) end),
     ($rss | tonumber),
     (.transport.timings.peak_rss_bytes / 1e6 | r(1)), (.file_bytes / 1e6 | r(2)),
     .timings.threads] | map(tostring) | join(",")' "$j" >>"$csv"
done
echo "wrote $csv" >&2

# 3. The markdown table.
md=$OUT.md
{
  echo "Command: \`scripts/bench_scaling.sh\`${ARGS:+ (ARGS=\"$ARGS\")}, default preset (converged bounces),"
  echo "one bake at a time. $MACHINE."
  echo "Phase times are CPU seconds (user + system, all threads) of the bake process between its"
  echo "stage log lines; \"wall\" is the whole bake's wall-clock time; peak memory is the process's"
  echo "maximum resident set. Placement is the importance particles and the Poisson-disk levels;"
  echo "the refinement of T is the gather of every refined receiver (Eq. 16-17, Fig. 5), 256 rays"
  echo "each (\"per refined receiver\": its CPU time over the refined receivers of all levels)."
  echo
  echo "| case | triangles | receiver levels | points | refined receivers | links | bounces | placement | refinement of T | per refined receiver | bounces | total CPU | wall | peak memory | file |"
  echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
  tail -n +2 "$csv" | awk -F, '
    function n(x,   s, out) { s = sprintf("%d", x); out = "";
      while (length(s) > 3) { out = "," substr(s, length(s) - 2) out; s = substr(s, 1, length(s) - 3) }
      return s out }
    function t(x) { if (x == "") return "-";
      return x >= 60 ? sprintf("%d:%04.1f", int(x / 60), x - 60 * int(x / 60)) : sprintf("%.1f s", x) }
    function ms(x) { return x == "" ? "-" : sprintf("%.2f ms", x) }
    { printf "| %s | %s | %d | %s | %s | %s | %d | %s | %s | %s | %s | %s | %s | %s MB | %.1f MB |\n",
        $1, n($4), $5, n($6), n($21), n($7), $9, t($18), t($19), ms($22), t($20), t($17), t($16), n($23), $25 }'
  bins=$(for c in $seen; do if [[ -s $WORK/$c.bin ]]; then echo "$(cat "$WORK/$c.bin"): $c"; fi; done |
         awk -F': ' '{b[$1] = b[$1] (b[$1] ? ", " : "") $2} END {for (k in b) print "- " k ": " b[k]}' | sort)
  if [[ -n $bins ]]; then
    echo
    echo "Bake binaries:"
    echo "$bins"
  fi
} >"$md"
echo "wrote $md" >&2

# 4. The plot.
if [[ -x $PLOT ]]; then
  "$PLOT" "$csv" --out "$OUT.png"
else
  echo "no plot_scaling binary ($PLOT): cargo build --release -p mlt-plot; the CSV and table are written" >&2
fi
cat "$md"
