#!/usr/bin/env bash
# Tiled reconstruction (--tile): wall time, peak memory and the tiled/untiled mesh difference
# on the bunny scans (0.5 mm) and the dragon scans (1 mm) at several tile sizes, and on a
# synthetic terrain of 1M and N million points (bench/terrain.py, same density, exact
# normals) untiled, with --tile 512 and with --tile auto --max-memory 1G. A tiled run of a PLY
# file with normals streams it (the point stages a region at a time) when the points would take
# over half of --max-memory, or with --stream on: "point stages" says which. Then the same
# terrain as LAS without normals, estimated and turned up (--up 0,0,1), streamed too.
#   bench/tiles.sh [build-dir] [millions=20]   (needs ../shared/data; run scripts/setup.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build}
MILLIONS=${2:-20}
BIN=$BUILD/vdbrecon
OUT=bench/out/tiles
source bench/common.sh
export PYTHONPATH=$BUILD/python
machine_line

# row LABEL INPUT REFERENCE-MESH ARGS...: one table row; the mesh goes to $OUT/LABEL.ply.
row() {
  local label=$1 input=$2 ref=$3; shift 3
  /usr/bin/time -f "%e %M" -o "$OUT/time.txt" "$BIN" "$input" -o "$OUT/$label.ply" --no-vdb \
    --threads 2 "$@" 2>"$OUT/$label.log" >/dev/null
  read -r w r < "$OUT/time.txt"
  local tiles
  tiles=$(grep -o "tiles: [0-9]* tiles of [0-9]*^3 voxels, halo [0-9]*" "$OUT/$label.log" || echo "untiled")
  local points
  points=$(grep -o "in [0-9]* regions, the largest [0-9]*" "$OUT/$label.log" |
    sed 's/in \([0-9]*\) regions, the largest \([0-9]*\)/streamed: \1 regions, largest \2/' ||
    echo "in memory")
  local diff="(reference)"
  [ "$ref" = - ] || diff=$(/usr/bin/python3 bench/mesh_diff.py "$ref" "$OUT/$label.ply")
  printf "| %s | %s | %s | %s | %s | %d | %s |\n" "$label" "$*" "$points" "$tiles" "$w" \
    "$((r / 1024))" "$diff"
}

echo
echo "| run | options | point stages | tiles | wall s | peak MB | mesh vs untiled |"
echo "|---|---|---|---|---|---|---|"
row bunny "$BUNNY" - --voxel 0.0005
for t in 256 128 64; do row "bunny-$t" "$BUNNY" "$OUT/bunny.ply" --voxel 0.0005 --tile "$t"; done
row bunny-128-stream "$BUNNY" "$OUT/bunny.ply" --voxel 0.0005 --tile 128 --stream on
DRAGON=$DATA/stanford_dragon/dragon_stand_aligned.ply
row dragon "$DRAGON" - --voxel 0.001
for t in 128 64; do row "dragon-$t" "$DRAGON" "$OUT/dragon.ply" --voxel 0.001 --tile "$t"; done
row dragon-128-stream "$DRAGON" "$OUT/dragon.ply" --voxel 0.001 --tile 128 --stream on

# Terrain: the same density (0.45 m spacing) over 447 m (1M points) and 2000 m (20M).
T1=$OUT/terrain-1M-input.ply
TN=$OUT/terrain-${MILLIONS}M-input.ply
[ -f "$T1" ] || /usr/bin/python3 bench/terrain.py "$T1" 1 --size 447
size=$(awk -v m="$MILLIONS" 'BEGIN {print 447 * sqrt(m)}')
[ -f "$TN" ] || /usr/bin/python3 bench/terrain.py "$TN" "$MILLIONS" --size "$size"
row terrain-1M "$T1" - --voxel 0.62
row terrain-1M-auto "$T1" "$OUT/terrain-1M.ply" --voxel 0.62 --tile auto --max-memory 1G
row terrain-1M-stream "$T1" "$OUT/terrain-1M.ply" --voxel 0.62 --tile auto --max-memory 1G \
  --stream on
row "terrain-${MILLIONS}M" "$TN" - --voxel 0.62
row "terrain-${MILLIONS}M-512" "$TN" "$OUT/terrain-${MILLIONS}M.ply" --voxel 0.62 --tile 512
row "terrain-${MILLIONS}M-auto" "$TN" "$OUT/terrain-${MILLIONS}M.ply" --voxel 0.62 --tile auto --max-memory 1G
row "terrain-${MILLIONS}M-off" "$TN" "$OUT/terrain-${MILLIONS}M.ply" --voxel 0.62 --tile auto \
  --max-memory 1G --stream off

# Airborne-style input: the same terrain points (the same seed) as LAS without normals, whose
# normals are estimated and turned up (--up 0,0,1): each point on its own, so the tiled run
# streams it too. The reference for the 20M run is the tiled run that reads it whole (the
# untiled one needs about 5 GB).
L1=$OUT/terrain-1M-input.las
LN=$OUT/terrain-${MILLIONS}M-input.las
[ -f "$L1" ] || /usr/bin/python3 bench/terrain.py "$L1" 1 --size 447 --las
[ -f "$LN" ] || /usr/bin/python3 bench/terrain.py "$LN" "$MILLIONS" --size "$size" --las
row las-1M "$L1" - --voxel 0.62 --up 0,0,1
row las-1M-stream "$L1" "$OUT/las-1M.ply" --voxel 0.62 --up 0,0,1 --tile auto --max-memory 1G \
  --stream on
row "las-${MILLIONS}M-off" "$LN" - --voxel 0.62 --up 0,0,1 --tile auto --max-memory 1G \
  --stream off
row "las-${MILLIONS}M-auto" "$LN" "$OUT/las-${MILLIONS}M-off.ply" --voxel 0.62 --up 0,0,1 \
  --tile auto --max-memory 1G
