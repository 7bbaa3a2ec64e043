#!/usr/bin/env bash
# Textures for planar regions (--texture) on the colour scans: the table scene (Kinect stereo,
# 8 mm) and the Redwood living-room fragment (1 cm). Per scan, best of $REPEAT runs of
# `--planes` and of `--planes --texture` (which also writes the OBJ's atlas): wall time, peak
# memory, the texture stage's time, the atlas and how many of its texels points reached.
#   bench/texture.sh [build-dir]   (needs ../shared/data; run scripts/setup.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build}
BIN=$BUILD/vdbrecon
OUT=bench/out/texture
source bench/common.sh
machine_line

case_row() {
  local label=$1 input=$2 voxel=$3
  best_of "$OUT/$label.planes.log" "$BIN" "$input" -o "$OUT/$label.planes.obj" --voxel "$voxel" --no-vdb --planes
  local wp=$WALL rp=$RSS
  best_of "$OUT/$label.texture.log" "$BIN" "$input" -o "$OUT/$label.obj" --voxel "$voxel" --no-vdb --texture
  local t
  t=$(grep -o "texture: [0-9]* regions in a [0-9]* x [0-9]* atlas, texel [0-9.e-]*; [0-9]* points coloured [0-9]* of [0-9]* texels" "$OUT/$label.texture.log")
  local stage
  stage=$(grep -o "texture [0-9.]* s" "$OUT/$label.texture.log" | awk '{print $2}')
  echo "| $label ($voxel) | $wp s / $rp MB | $WALL s / $RSS MB | $stage | ${t#texture: } | $(stat -c %s "$OUT/$label.texture.png") |"
}

echo
echo "| scan (voxel) | --planes: wall / peak | --texture: wall / peak | texture stage s | atlas | PNG bytes |"
echo "|---|---|---|---|---|---|"
case_row table "$DATA/pcl_kinect/table_scene_mug_stereo_textured.ply" 0.008
case_row fragment "$DATA/redwood_livingroom/fragment.ply" 0.01
