#!/usr/bin/env bash
# Range-image fusion benchmark (issue 23): one rendered depth sequence of the bunny's reference
# mesh (bench/fusion_scene: 30 poses on a sphere, 640x480, Gaussian depth noise of 0.4 voxel,
# 16-bit PNG, and 8-bit colour images of the mesh painted with bench/paint.py's pattern), fused
# by `vdbrecon fuse` and by Open3D's ScalableTSDFVolume with RGB8 colour (sdf_trunc 4 voxels,
# bench/fusion_open3d.py); F-score and Chamfer against the mesh, the vertex colours' error
# against the pattern, pieces, boundary edges, wall time and peak memory. Prints a markdown
# table for bench/RESULTS.md.
#   bench/fusion.sh [build-dir]   (needs ../shared/data; installs python3-open3d; run scripts/setup.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build}
OUT=bench/out/fusion
VOXEL=${VOXEL:-0.001}
FRAMES=${FRAMES:-30}
REF=../shared/data/stanford_bunny/bun_zipper_gt.ply
source bench/harness.sh   # common.sh, ensure_packages
ensure_packages time python3-open3d
mkdir -p "$OUT/scene"
rm -f "$OUT"/scene/*
"$BUILD/tests/fusion_scene" "$REF" "$OUT/scene" "$FRAMES" 640 480 "$(/usr/bin/python3 -c "print(0.4 * $VOXEL)")" >/dev/null

machine_line
echo
echo "Bunny reference mesh rendered from $FRAMES poses (640x480, noise 0.4 voxel), --voxel $VOXEL;"
echo "best wall time of $REPEAT runs each; quality against the mesh (\`vdbrecon eval --tau $VOXEL\`)."
echo
echo "| tool | wall s | peak RSS MB | faces | pieces | boundary edges | F@1 voxel | Chamfer-L1 um | colour error mean / p99 |"
echo "|---|---|---|---|---|---|---|---|---|"
run_tool() {  # name, mesh, command...
  local name=$1 mesh=$2
  shift 2
  best_of "$OUT/best.log" "$@"
  "$BUILD/vdbrecon" eval "$mesh" "$REF" --tau "$VOXEL" >"$OUT/eval.json"
  local colour
  colour=$(/usr/bin/python3 bench/paint.py "$mesh" "$REF")
  /usr/bin/python3 - "$OUT/eval.json" "$name" "$WALL" "$RSS" "$colour" <<'PY'
import json, sys
e = json.load(open(sys.argv[1]))
r = e["recon"]
print(f"| {sys.argv[2]} | {float(sys.argv[3]):.2f} | {int(sys.argv[4])} | {r['faces']} | "
      f"{r['components']} | {r['boundary_edges']} | {e['fscore'][0]['fscore']:.4f} | "
      f"{e['chamfer_l1'] * 1e6:.1f} | {sys.argv[5]} |")
PY
}
run_tool "vdbrecon fuse" "$OUT/vdbrecon.ply" "$BUILD/vdbrecon" fuse "$OUT/scene/transforms.json" \
  -o "$OUT/vdbrecon.ply" --voxel "$VOXEL" --no-vdb
run_tool "vdbrecon fuse --fusion tsdf" "$OUT/vdbrecon-tsdf.ply" "$BUILD/vdbrecon" fuse \
  "$OUT/scene/transforms.json" -o "$OUT/vdbrecon-tsdf.ply" --voxel "$VOXEL" --no-vdb --fusion tsdf
run_tool "Open3D ScalableTSDFVolume" "$OUT/open3d.ply" /usr/bin/python3 bench/fusion_open3d.py \
  "$OUT/scene/transforms.json" "$OUT/open3d.ply" "$VOXEL"
