#!/usr/bin/env bash
# Real scans with vdbrecon's DEFAULT options (only --voxel set, from the MANIFEST): the Autzen
# LiDAR tile (LAS original and its shifted PLY twin, feet, 4.4), the room laser scan (0.1 m),
# the Kinect stereo table scene (8 mm), the Redwood living-room fragment (1 cm) and the Kinect
# frame capture0001 (13 mm). For each: faces, pieces (edge-connected face components), mesh
# area, the share of the area facing down (face normal cross(b - a, c - a) with z < 0), the
# share of the input points within 1 voxel of the mesh (exact point-to-triangle distance; in
# brackets, within 1 voxel of a mesh vertex) and the wall time of the whole process; then the
# clean and normals lines of each run's log. Prints markdown for RESULTS.md, with the machine,
# commit, date and load. Meshes and logs go to bench/out/scenes/ (git-ignored).
#
#   bench/scenes.sh                                  (vdbrecon from build/vdbrecon)
#   VDBRECON=/path/to/vdbrecon bench/scenes.sh       (BIN= is accepted too, as in the others)
#   nice -n 10 bench/scenes.sh | tee bench/out/scenes.md
#
# Environment: VDBRECON (or BIN) the binary; DATA the corpus (default ../shared/data from the
# repository root); OUT the output folder; TIMEOUT seconds per run (default 1200); SCENES a
# space-separated subset of the names below (e.g. SCENES="room table").
# Needs /usr/bin/python3 with numpy (bench/scene_stats.py; no scipy). A missing corpus prints a
# message and exits 0. The "facing down" share means "facing up or down" only for z-up scans
# (Autzen, and the room scan if its z is up); the Kinect/stereo frames are in the camera frame
# (+z is the viewing direction), where surfaces seen by the camera face -z.
set -euo pipefail
case "${1:-}" in -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0;; esac

# The binary, resolved before the cd so that a relative VDBRECON works from the caller's cwd.
BIN=${VDBRECON:-${BIN:-}}
if [ -n "$BIN" ] && [ -e "$BIN" ]; then BIN=$(readlink -f "$BIN"); fi
cd "$(dirname "$0")/.."
BIN=${BIN:-build/vdbrecon}
DATA=${DATA:-../shared/data}
OUT=${OUT:-bench/out/scenes}
TIMEOUT=${TIMEOUT:-1200}
PY=/usr/bin/python3

if [ ! -d "$DATA" ]; then
  echo "bench/scenes.sh: no corpus at '$DATA' (expected ../shared/data next to the repository; set DATA=...); nothing to run."
  exit 0
fi
[ -x "$BIN" ] || { echo "bench/scenes.sh: no vdbrecon binary at '$BIN' (set VDBRECON=path/to/vdbrecon)" >&2; exit 1; }
"$PY" -c 'import numpy' 2>/dev/null || { echo "bench/scenes.sh: $PY has no numpy" >&2; exit 1; }
mkdir -p "$OUT"

# name | input | voxel
ALL=(
  "autzen-las|$DATA/pdal_autzen/autzen_trim.las|4.4"
  "autzen-ply|$DATA/pdal_autzen/autzen_trim.ply|4.4"
  "room|$DATA/pcl_laser/room_scan1.ply|0.1"
  "table|$DATA/pcl_kinect/table_scene_mug_stereo_textured.ply|0.008"
  "fragment|$DATA/redwood_livingroom/fragment.ply|0.01"
  "capture0001|$DATA/pcl_kinect/capture0001.ply|0.013"
)

echo "vdbrecon: $BIN ($("$BIN" --version 2>/dev/null | head -n 1 || true), built $(date -u -r "$BIN" '+%F %H:%M UTC'))"
echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo), $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
echo "checkout: $(git rev-parse --short HEAD 2>/dev/null || echo unknown)$(git diff --quiet HEAD -- src include apps 2>/dev/null || echo ' + uncommitted changes in src/include/apps') (the binary may have been built from another state)  date: $(date -u '+%F %H:%M UTC')"
echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg) ($(nproc) cores)"
echo "options: defaults except --voxel (no --threads: every core)"
echo
"$PY" bench/scene_stats.py header

NOTES=()
for entry in "${ALL[@]}"; do
  IFS='|' read -r name input voxel <<<"$entry"
  if [ -n "${SCENES:-}" ] && [[ " $SCENES " != *" $name "* ]]; then continue; fi
  if [ ! -f "$input" ]; then
    echo "| $name | $voxel | - | - | - | - | - | - | (missing: $input) |"
    continue
  fi
  mesh=$OUT/$name.ply log=$OUT/$name.log
  rm -f "$mesh"
  rc=0
  start=$(date +%s.%N)
  timeout "$TIMEOUT" "$BIN" "$input" -o "$mesh" --voxel "$voxel" >"$OUT/$name.stdout" 2>"$log" || rc=$?
  wall=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN {printf "%.2f", b - a}')
  status=ok
  if [ "$rc" -eq 124 ]; then status=timeout; elif [ "$rc" -ne 0 ]; then status="exit $rc"; fi
  if [ "$status" = ok ] && [ ! -s "$mesh" ]; then status="no mesh"; fi
  "$PY" bench/scene_stats.py row "$name" "$mesh" "$input" "$voxel" "$wall" "$status" ||
    echo "| $name | $voxel | - | - | - | - | - | - | $wall (scene_stats.py failed) |"
  lines=$(grep -E 'vdbrecon: (clean|normals|outliers):|orient' "$log" || true)
  if [ "$status" != ok ]; then  # and the log's last lines, for the error
    tail=$(tail -n 3 "$log" | grep -vE 'vdbrecon: (clean|normals|outliers):|orient' || true)
    lines="${lines:+$lines$'\n'}${tail:-(empty log)}"
  fi
  NOTES+=("$name|${lines:-(no clean/normals line in the log)}")
done

echo
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
echo
echo "From each run's log ($OUT/NAME.log):"
echo
for n in "${NOTES[@]}"; do
  echo "- ${n%%|*}:"
  while IFS= read -r l; do echo "  - \`$l\`"; done <<<"${n#*|}"
done
