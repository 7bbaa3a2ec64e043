#!/usr/bin/env bash
# Peer comparison (issue 5): on the bunny and dragon scans (scored against their reference
# meshes; the dragon's completeness and recall only where the reference lies within 2 mm of a
# scan point) and a Kinect frame (no reference: time and topology), runs every vdbrecon mesher
# at the manifest's voxel and half of it, Open3D screened Poisson (depth 9 and 10, density trim)
# and ball pivoting, and vdb_tool's points-to-level-set recipe, all in this one invocation so
# the ratios are taken on the same machine state. Prints one markdown table for RESULTS.md.
#   BIN=build/vdbrecon bench/compare.sh    (needs ../shared/data; installs python3-open3d and
#                                           libopenvdb-tools when missing)
#   QUICK=1: 20 % subsets of the scans, the manifest voxel only, Poisson depth 8, 200k samples.
#   POISSON_THREADS=N: Open3D Poisson's n_threads (default -1, every core; its thread pool
#   spin-waits, which costs 2-5x on a machine busy with other work: use 1 there).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=bench/out/compare
source bench/harness.sh
ensure_packages time python3-open3d libopenvdb-tools
POISSON_THREADS=${POISSON_THREADS:--1}

# name | scan | reference mesh | manifest voxel | radius of the completeness mask | extra voxel
# (the bunny's 0.5 mm: issue 5's speed target is stated there)
DATASETS=(
  "bunny|$BUNNY|$GT|0.0009||0.0005"
  "dragon|$DATA/stanford_dragon/dragon_stand_aligned.ply|$DATA/stanford_dragon/dragon_vrip_res3_gt.ply|0.001|0.002|"
  "kinect|$DATA/pcl_kinect/capture0001.ply||0.013||"
)
if [ "$QUICK" = 1 ]; then DEPTHS=(8); else DEPTHS=(9 10); fi

mm() { awk -v v="$1" 'BEGIN {printf "%g mm", v * 1000}'; }

# one METHOD SETTING MESH CMD...: times CMD (which writes MESH), scores MESH against $REF (masked
# by $MASK within $MASK_DIST when set) and adds the row for dataset $NAME.
one() {
  local method=$1 setting=$2 mesh=$3 json=-; shift 3
  rm -f "$mesh"
  echo "bench: $NAME / $method / $setting ..." >&2
  timed "${mesh%.ply}.log" "$@"
  if [ "$RC" -eq 0 ] && [ -s "$mesh" ]; then
    json=${mesh%.ply}.json
    score "$mesh" "$json" "$REF" "$MASK" "$MASK_DIST" || json=-
  fi
  add_row "$NAME" "$method" "$setting" "${mesh%.ply}.log" "$json" "$([ -n "$REF" ] && echo scored || echo topology)"
}

START=$(date +%s)
LOAD_START=$(load_line)
for d in "${DATASETS[@]}"; do
  IFS='|' read -r NAME scan REF voxel MASK_DIST extra_voxel <<<"$d"
  MASK=""
  [ -z "$MASK_DIST" ] || MASK=$scan
  input=$scan
  if [ "$QUICK" = 1 ]; then
    input=$OUT/$NAME.20pct.ply
    [ -s "$input" ] || $PY bench/synth.py subsample "$scan" "$input" 0.2
  fi
  voxels=("$voxel")
  [ "$QUICK" = 1 ] || voxels+=("$(awk -v v="$voxel" 'BEGIN {print v / 2}')")
  [ "$QUICK" = 1 ] || [ -z "$extra_voxel" ] || voxels+=("$extra_voxel")
  for v in "${voxels[@]}"; do
    for m in vdb mc dc; do
      one "vdbrecon $m" "voxel $(mm "$v")" "$OUT/$NAME.vdbrecon-$m-$v.ply" \
        "$BIN" "$input" -o "$OUT/$NAME.vdbrecon-$m-$v.ply" --voxel "$v" --mesher "$m" --no-vdb
    done
  done
  for depth in "${DEPTHS[@]}"; do
    one "Open3D Poisson" "depth $depth, trim 1 %$([ "$POISSON_THREADS" = -1 ] ||
      echo ", $POISSON_THREADS thread(s)")" "$OUT/$NAME.poisson-$depth.ply" \
      $PY bench/peers.py poisson "$input" "$OUT/$NAME.poisson-$depth.ply" --depth "$depth" \
      --trim 0.01 --threads "$POISSON_THREADS"
  done
  one "Open3D ball pivoting" "radii 3, 6 x spacing" "$OUT/$NAME.bpa.ply" \
    $PY bench/peers.py bpa "$input" "$OUT/$NAME.bpa.ply" --radii 3,6
  one "vdb_tool" "voxel $(mm "$voxel")" "$OUT/$NAME.vdb_tool.ply" \
    vdb_tool -read "$input" -points2ls voxel="$voxel" radius=2 width=3 -dilate radius=2 \
    -gauss iter=1 size=1 -erode radius=2 -ls2mesh adapt=0.25 -write "$OUT/$NAME.vdb_tool.ply"
  # The recipe's surface is the union of 2-voxel particle spheres, 2 voxels outside the scan:
  # eroding by the particle radius too puts it back where the samples are.
  one "vdb_tool + erode 2" "voxel $(mm "$voxel")" "$OUT/$NAME.vdb_tool_erode.ply" \
    vdb_tool -read "$input" -points2ls voxel="$voxel" radius=2 width=3 -dilate radius=2 \
    -gauss iter=1 size=1 -erode radius=2 -erode radius=2 -ls2mesh adapt=0.25 \
    -write "$OUT/$NAME.vdb_tool_erode.ply"
done

machine_line
echo
$PY bench/table.py compare "$ROWS"
cat <<NOTES

Times are one run each of the whole process (/usr/bin/time: reading, reconstruction, writing;
the Open3D rows include starting Python and importing open3d), every tool on all $(nproc) cores
(Open3D Poisson: n_threads $POISSON_THREADS, -1 meaning all).
vdbrecon runs with --no-vdb. Open3D Poisson: scale 1.1, no linear fit, vertices below the 1 %
density quantile removed. Ball pivoting: radii 3x and 6x the mean nearest-neighbour spacing.
vdb_tool: \`-points2ls voxel=V radius=2 width=3 -dilate radius=2 -gauss iter=1 size=1 -erode
radius=2 -ls2mesh adapt=0.25\` (the recipe of its -help), and the same with a second
\`-erode radius=2\` that takes off the particle radius; its polygons are fanned into triangles
when read. All meshes scored by \`vdbrecon eval\` ($SAMPLES samples, tau 0.5 and
1 mm); dragon completeness, recall and F only where the reference lies within 2 mm of a scan
point (--mask-points, --mask-distance 0.002); the Kinect frame has no reference.
NOTES
echo
echo "Load: $LOAD_START at the start, $(load_line) at the end; the whole run took" \
  "$(( ($(date +%s) - START + 30) / 60 )) min. QUICK=$QUICK, eval samples $SAMPLES."
