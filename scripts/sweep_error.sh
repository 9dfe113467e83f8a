#!/usr/bin/env bash
# Error against run time (issue 5): for one scene, bake with a range of settings (epsilon, and
# gather rays and receiver levels at the paper's epsilon), and for each record the bake time,
# links, file size, the median per-frame CPU relighting time with a moving light, and the error
# of the headless indirect and final images against the brute-force reference (view render
# --reference) for several light positions (averaged over the lights).
#
# Usage: scripts/sweep_error.sh SCENE NAME [OUT_PREFIX]
#   SCENE       manifest / builtin name given to bake (e.g. builtin:cornell, scenes/sponza.toml)
#   NAME        short name used in the output file names (docs/error_NAME.{csv,md} and
#               docs/error_NAME_vs_{bake,frame}.png unless OUT_PREFIX is given)
# Environment (defaults in brackets):
#   SETTINGS    one setting per line, "LABEL|PAPER(0/1)|bake arguments"
#               [the default bake (converged), the paper preset (4 bounces), the default at
#               epsilon 0.05 and 0.0125, the default with 5 receiver levels]
#   ROWS        use only the first ROWS settings [all]
#   LIGHTS      light positions x,y,z separated by spaces [the scene's light]
#   WIDTH HEIGHT image size of the comparison [128 128]
#   SPP         reference paths per pixel [512]
#   FRAMES      frames of the moving-light timing [16]
#   WORK        scratch directory [target/sweep_NAME]
#   BIN         directory of the release binaries [target/release]
# Build first: cargo build --release -p mlt-bake -p mlt-view -p mlt-plot
# (plot_sweep is the package mlt-plot, in scripts/plot_sweep).
set -euo pipefail

SCENE=${1:?usage: sweep_error.sh SCENE NAME [OUT_PREFIX]}
NAME=${2:?usage: sweep_error.sh SCENE NAME [OUT_PREFIX]}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
OUT=${3:-$ROOT/docs/error_$NAME}
BIN=${BIN:-$ROOT/target/release}
WORK=${WORK:-$ROOT/target/sweep_$NAME}
WIDTH=${WIDTH:-128}
HEIGHT=${HEIGHT:-128}
SPP=${SPP:-512}
FRAMES=${FRAMES:-16}
SETTINGS=${SETTINGS:-"default (converged)|0|
paper preset|1|--preset paper
default; epsilon 0.05|0|--epsilon 0.05
default; epsilon 0.0125|0|--epsilon 0.0125
default; 5 levels|0|--receiver-levels 5"}
if [[ -n ${ROWS:-} ]]; then
  SETTINGS=$(head -n "$ROWS" <<<"$SETTINGS")
fi
for b in bake view plot_sweep; do
  [[ -x $BIN/$b ]] || { echo "missing $BIN/$b: cargo build --release -p mlt-bake -p mlt-view -p mlt-plot" >&2; exit 1; }
done
mkdir -p "$WORK" "$(dirname "$OUT")"
CMD="scripts/sweep_error.sh $SCENE $NAME (WIDTH=$WIDTH HEIGHT=$HEIGHT SPP=$SPP FRAMES=$FRAMES LIGHTS=\"${LIGHTS:-default}\" ROWS=${ROWS:-all})"

# 1. Bakes, file sizes and frame times.
i=0
declare -a FILES LABELS PAPERS
while IFS= read -r line; do
  [[ -z $line ]] && continue
  IFS='|' read -r label paper args <<<"$line"
  f=$WORK/s$i.mlt
  if [[ ! -s $f || ! -s $WORK/s$i.json ]]; then
    echo "== bake [$label]: $BIN/bake $SCENE $args" >&2
    # shellcheck disable=SC2086
    "$BIN/bake" "$SCENE" -o "$f" --stats-json "$WORK/s$i.json" -q $args >&2
  fi
  if [[ ! -s $WORK/s$i.frames.json ]]; then
    "$BIN/view" timings "$f" --frames "$FRAMES" --timings-out "$WORK/s$i.frames.json" >&2
  fi
  FILES[i]=$f; LABELS[i]=$label; PAPERS[i]=$paper
  i=$((i + 1))
done <<<"$SETTINGS"
n=$i

# 2. Light positions: the scene's own light unless given.
if [[ -z ${LIGHTS:-} ]]; then
  LIGHTS=$(jq -r '.meta.light.position | map(tostring) | join(",")' "$WORK/s0.json")
fi

# 3. The reference per light (from the first file: all share camera and scene).
k=0
for L in $LIGHTS; do
  r=$WORK/ref$k
  if [[ ! -s $r/reference.json ]]; then
    echo "== reference, light $L, $SPP spp" >&2
    "$BIN/view" render "${FILES[0]}" --out "$r" --width "$WIDTH" --height "$HEIGHT" \
      --light-pos "$L" --reference "$SPP" >&2
  fi
  k=$((k + 1))
done
nl=$k

# 4. Each setting's images against the references.
CSV=$OUT.csv
echo "label,paper,epsilon,gather_rays,receiver_levels,bake_s,links,file_bytes,frame_ms,indirect_rel_rmse,indirect_mean_rel,indirect_ratio,final_rel_rmse,final_mean_rel,final_ratio,noise_indirect_rel_rmse,noise_final_rel_rmse,lights" >"$CSV"
for ((i = 0; i < n; i++)); do
  s=$WORK/s$i
  k=0; cmps=()
  for L in $LIGHTS; do
    d=$s.light$k
    "$BIN/view" render "${FILES[i]}" --out "$d" --width "$WIDTH" --height "$HEIGHT" --light-pos "$L" >&2
    "$BIN/view" compare "$WORK/ref$k" "$d" --json >"$d.cmp.json"
    cmps+=("$d.cmp.json")
    k=$((k + 1))
  done
  avg() { jq -s "map($1) | add / length" "${cmps[@]}"; }
  printf '%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s\n' \
    "${LABELS[i]//,/;}" "${PAPERS[i]}" \
    "$(jq '.transport.params.epsilon' "$s.json")" \
    "$(jq '.transport.params.gather_rays' "$s.json")" \
    "$(jq '.transport.params.receiver_levels' "$s.json")" \
    "$(jq '.timings.total_s' "$s.json")" \
    "$(jq '.transport.stats.links' "$s.json")" \
    "$(jq '.file_bytes' "$s.json")" \
    "$(jq '.median_ms.total // .cpu_median_ms.total' "$s.frames.json")" \
    "$(avg .indirect.relative_rmse)" "$(avg .indirect.mean_relative_error_lit)" "$(avg .indirect.ratio_of_means)" \
    "$(avg .final_image.relative_rmse)" "$(avg .final_image.mean_relative_error_lit)" "$(avg .final_image.ratio_of_means)" \
    "$(avg .indirect.noise_relative_rmse)" "$(avg .final_image.noise_relative_rmse)" \
    "$nl" >>"$CSV"
done

# 5. Markdown table and plots.
MD=$OUT.md
{
  echo "# Error against run time: $NAME"
  echo
  echo "Made by \`$CMD\` on $(nproc) cores ($(date -u +%Y-%m-%d))."
  echo "Errors are against the brute-force path-traced reference (\`view render --reference $SPP\`,"
  echo "${WIDTH}x${HEIGHT} pixels), on luminance, averaged over $nl light position(s): $LIGHTS."
  echo "Relative RMSE = RMS(test - ref) / mean(ref); mean rel. error over lit pixels (ref > 1 % of its mean);"
  echo "ratio = mean(test) / mean(ref). The reference's own noise floor under the relative RMSE is given last."
  echo "Frame time: median CPU relighting (direct at senders, pull-push, S e with the fine bounces, the bounce-light feedback, flatten) over $FRAMES frames with a moving light."
  echo
  echo "| setting | paper | epsilon | gather rays | levels | bake (s) | links | file (MB) | frame (ms) | indirect rel. RMSE | indirect mean rel. | indirect ratio | final rel. RMSE | final mean rel. | final ratio | ref. noise (indirect / final) |"
  echo "|---|:-:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
  tail -n +2 "$CSV" | awk -F, '{printf "| %s | %s | %g | %d | %d | %.1f | %d | %.2f | %.1f | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f / %.3f |\n", $1, ($2 == 1 ? "yes" : ""), $3, $4, $5, $6, $7, $8 / 1e6, $9, $10, $11, $12, $13, $14, $15, $16, $17}'
  echo
  echo "![error vs bake time](error_${NAME}_vs_bake.png) ![error vs frame time](error_${NAME}_vs_frame.png)"
} >"$MD"
"$BIN/plot_sweep" "$CSV" --out "$OUT" --title "$NAME"
echo "wrote $CSV, $MD, ${OUT}_vs_bake.png, ${OUT}_vs_frame.png" >&2
