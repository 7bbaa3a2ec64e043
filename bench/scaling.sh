#!/usr/bin/env bash
# Scaling (issue 5): vdbrecon's time and peak memory against the number of points, at
# --threads 1 and 2. Inputs: the bunny scans subsampled to 10, 25, 50 and 100 %, and a synthetic
# 5-million-point scan (48 noisy virtual range scans of the bunny's reference mesh, made once by
# bench/synth.py and kept in bench/out). All at --voxel 0.0005, so the surface and the mesh stay
# about the same while the points grow; each mesh is scored against the bunny reference. Then the
# bunny subsamples once more at 2 threads with the automatic voxel (1.4 x the median sample spacing, the
# default without --voxel), where the volume follows the sampling density: the linear-cost case
# (best of AUTO_REPEAT=5 runs each).
# Prints one markdown table for bench/RESULTS.md; "grids MB" and "points MB" are the memory of the
# grids written to the .vdb (the splat's three and the density grid made for the file) and of the
# cloud as read, from vdbrecon's log (the .vdb is written: the default).
#   BIN=build/vdbrecon bench/scaling.sh    (QUICK=1: a 1M-point synthetic scan, 200k samples)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=bench/out/scaling
source bench/harness.sh
ensure_packages time python3-open3d
if [ "$QUICK" = 1 ]; then SYNTH_POINTS=${SYNTH_POINTS:-1000000}; fi
SYNTH_POINTS=${SYNTH_POINTS:-5000000}
VOXEL=0.0005

START=$(date +%s)
LOAD_START=$(load_line)
inputs=()
for pct in 10 25 50; do
  f=$OUT/bunny-$pct.ply
  [ -s "$f" ] || $PY bench/synth.py subsample "$BUNNY" "$f" "$(awk -v p=$pct 'BEGIN {print p / 100}')"
  inputs+=("bunny $pct %|$f")
done
inputs+=("bunny 100 %|$BUNNY")
synth=$OUT/synthetic-$SYNTH_POINTS.ply
if [ ! -s "$synth" ]; then
  echo "bench: generating $synth" >&2
  timed "$OUT/synthetic.log" $PY bench/synth.py scans "$GT" "$synth" --points "$SYNTH_POINTS"
  [ "$RC" -eq 0 ] || { cat "$OUT/synthetic.log" >&2; exit 1; }
  echo "bench: generated in ${WALL} s" >&2
fi
inputs+=("synthetic|$synth")

# The VM's other tenants make one run's time vary by up to 1.5x, as much as the differences
# these runs are there to show (1 against 2 threads, time per point): every row is the best of
# several runs by the sum of its stage times, the runs taking turns.
stage_sum() {
  stage_times "$1" read outliers normals splat mesh |
    awk -F'|' '{for (i = 1; i <= NF; ++i) if ($i == "-") exit; print $1 + $2 + $3 + $4 + $5}'
}
declare -A best_sum best_row
# keep_best SLUG: after a `timed` run into $OUT/SLUG.try.log, keeps it as $OUT/SLUG.log (and
# its numbers) when its stages took less time than the best so far.
keep_best() {
  local sum
  sum=$(stage_sum "$OUT/$1.try.log")
  [ "$RC" -eq 0 ] && [ -n "$sum" ] || sum=1e9
  if better "$sum" "${best_sum[$1]:-}"; then
    best_sum[$1]=$sum
    mv "$OUT/$1.try.log" "$OUT/$1.log"
    best_row[$1]="$RC $WALL $CPU $RSS"
  fi
}

# At --voxel 0.0005, 1 and 2 threads: the best of THREAD_REPEAT runs each.
THREAD_REPEAT=${THREAD_REPEAT:-3}
identical=yes
for entry in "${inputs[@]}"; do
  IFS='|' read -r label input <<<"$entry"
  points=$(grep -a -m1 '^element vertex' "$input" | cut -d' ' -f3)
  slug=$(echo "$label" | tr -d ' %')
  for round in $(seq "$THREAD_REPEAT"); do
    for threads in 2 1; do
      echo "bench: $label ($points points), $threads threads, run $round of $THREAD_REPEAT ..." >&2
      timed "$OUT/$slug.t$threads.try.log" "$BIN" "$input" -o "$OUT/$slug.t$threads.ply" \
        --voxel "$VOXEL" --threads "$threads"
      keep_best "$slug.t$threads"
    done
  done
  for threads in 2 1; do
    read -r RC WALL CPU RSS <<<"${best_row[$slug.t$threads]}"
    json=-
    if [ "$RC" -eq 0 ]; then
      json=$OUT/$slug.json
      [ "$threads" = 1 ] || score "$OUT/$slug.t$threads.ply" "$json" "$GT"
    fi
    add_row "$label" "$threads" "voxel 0.5 mm" "$OUT/$slug.t$threads.log" "$json" "$points"
  done
  cmp -s "$OUT/$slug.t1.ply" "$OUT/$slug.t2.ply" || identical=no
done
# The automatic-voxel runs (0.1-1 s each): the best of AUTO_REPEAT runs, the inputs taking turns.
AUTO_REPEAT=${AUTO_REPEAT:-5}
for round in $(seq "$AUTO_REPEAT"); do
  for entry in "${inputs[@]}"; do
    IFS='|' read -r label input <<<"$entry"
    [ "$label" = synthetic ] && continue
    points=$(grep -a -m1 '^element vertex' "$input" | cut -d' ' -f3)
    slug=$(echo "$label" | tr -d ' %')-auto
    echo "bench: $label ($points points), automatic voxel, run $round of $AUTO_REPEAT ..." >&2
    timed "$OUT/$slug.try.log" "$BIN" "$input" -o "$OUT/$slug.ply" --threads 2
    keep_best "$slug"
  done
done
for entry in "${inputs[@]}"; do
  IFS='|' read -r label input <<<"$entry"
  [ "$label" = synthetic ] && continue
  points=$(grep -a -m1 '^element vertex' "$input" | cut -d' ' -f3)
  slug=$(echo "$label" | tr -d ' %')-auto
  read -r RC WALL CPU RSS <<<"${best_row[$slug]}"
  json=-
  if [ "$RC" -eq 0 ]; then json=$OUT/$slug.json; score "$OUT/$slug.ply" "$json" "$GT"; fi
  add_row "$label" "2, auto voxel" "auto" "$OUT/$slug.log" "$json" "$points"
done

machine_line
echo
$PY bench/table.py scaling "$ROWS"
echo
echo "Best of $THREAD_REPEAT runs at --voxel 0.0005, best of $AUTO_REPEAT with the"
echo "automatic voxel, by the sum of the stage times;"
echo ".vdb written; times in seconds"
echo "(the stage columns from vdbrecon's log); meshes scored against bun_zipper_gt.ply"
echo "\"start-up MB\": what the process held before reading (executable and shared libraries, from"
echo "vdbrecon's log); \"peak - start-up\" is what the run added."
echo "($SAMPLES samples). Meshes identical for 1 and 2 threads: $identical. Synthetic scan: $(grep -a -m1 '^comment' "$synth" | cut -d' ' -f2-)."
echo
echo "Load: $LOAD_START at the start, $(load_line) at the end; the whole run took" \
  "$(( ($(date +%s) - START + 30) / 60 )) min. QUICK=$QUICK."
