#!/usr/bin/env bash
# Range-image fusion benchmark (issues 23 and 48): `vdbrecon fuse` (splat and --fusion tsdf) and
# Open3D's ScalableTSDFVolume (sdf_trunc 4 voxels, RGB8 colour where there is colour;
# bench/fusion_open3d.py) on the same 16-bit PNG files (transforms.json scenes written by
# bench/fusion_scene), side by side in one run:
#   bunny   the bunny's reference mesh from 30 poses on a sphere (0.4 m), noise 0.4 voxel,
#           colour painted with bench/paint.py's pattern, --voxel 1 mm (voxel > pixel footprint);
#   dragon  the dragon's reference mesh scaled to 1.6 m, 30 poses at 2.6 m, noise 2 mm, colour,
#           --voxel 5 mm: the voxel about the pixel footprint (3.8 mm), many kernels;
#   dragon4 the same frames at --voxel 4 mm (1.05 pixel footprints);
#   kinect  PCL's real Kinect frame capture0001 (0.9-3.9 m) as 30 frames of a static camera,
#           --voxel 1 cm;
#   table   PCL's real textured-stereo frame (colour) as 30 frames, --voxel 1 cm.
# Best wall time of $REPEAT rounds (the three tools run in turn each round); "x Open3D" is
# Open3D's best over the tool's best. Quality against the reference mesh where there is one
# (`vdbrecon eval --tau VOXEL`), the colour error against the painted pattern. Prints a markdown
# table for bench/RESULTS.md.
#   bench/fusion.sh [build-dir] [scene...]   (needs ../shared/data; installs python3-open3d)
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build}
shift || true
SCENES=${*:-bunny dragon dragon4 kinect table}
OUT=bench/out/fusion
FRAMES=${FRAMES:-30}
source bench/harness.sh   # common.sh, ensure_packages
ensure_packages time python3-open3d

# scene NAME: writes the scene's frames to $OUT/NAME/transforms.json (dragon4 reads the
# dragon's); sets FRAMES_DIR, VOXEL and REF (empty: no reference).
scene() {
  if [ "$1" = dragon4 ]; then  # the dragon's frames at a finer voxel
    [ -f "$OUT/dragon/transforms.json" ] || scene dragon
    FRAMES_DIR=$OUT/dragon VOXEL=0.004 REF=$OUT/dragon/reference.ply
    return
  fi
  local dir=$OUT/$1 gen=("$BUILD/tests/fusion_scene")
  mkdir -p "$dir"
  rm -f "$dir"/*
  case $1 in
    bunny) VOXEL=0.001 REF=$DATA/stanford_bunny/bun_zipper_gt.ply
      gen+=("$REF" "$dir" --noise 0.0004) ;;
    dragon) VOXEL=0.005 REF=$dir/reference.ply
      gen+=("$DATA/stanford_dragon/dragon_vrip_res3_gt.ply" "$dir" --scale 6.12 --noise 0.002) ;;
    kinect) VOXEL=0.01 REF="" gen+=(--pcd "$DATA/pcl_kinect/capture0001.pcd" "$dir") ;;
    table) VOXEL=0.01 REF="" gen+=(--pcd "$DATA/pcl_kinect/table_scene_mug_stereo_textured.pcd" "$dir") ;;
    *) echo "bench/fusion.sh: unknown scene '$1'" >&2; exit 2 ;;
  esac
  "${gen[@]}" --frames "$FRAMES" >/dev/null 2>"$dir/scene.log"
  FRAMES_DIR=$dir
}

# run_tool NAME OUT_DIR: one timed run of a tool on the scene's frames (mesh OUT_DIR/NAME.ply,
# its stderr in OUT_DIR/NAME.log); sets W (s) and R (KB).
run_tool() {
  local json=$FRAMES_DIR/transforms.json mesh=$2/$1.ply cmd
  case $1 in
    splat) cmd=("$BUILD/vdbrecon" fuse "$json" -o "$mesh" --voxel "$VOXEL" --no-vdb) ;;
    tsdf) cmd=("$BUILD/vdbrecon" fuse "$json" -o "$mesh" --voxel "$VOXEL" --no-vdb --fusion tsdf) ;;
    open3d) cmd=(/usr/bin/python3 bench/fusion_open3d.py "$json" "$mesh" "$VOXEL") ;;
  esac
  /usr/bin/time -f "%e %M" -o "$OUT/time.txt" "${cmd[@]}" >/dev/null 2>"$2/$1.log"
  read -r W R <"$OUT/time.txt"
}

machine_line
echo
echo "$FRAMES frames of 640x480 per scene; best wall time of $REPEAT rounds; quality against the"
echo "reference mesh (\`vdbrecon eval --tau VOXEL\`, F at one voxel)."
echo
echo "| scene | tool | wall s | x Open3D | peak MB | faces | pieces | F@1 voxel | Chamfer um | colour error mean / p99 |"
echo "|---|---|---|---|---|---|---|---|---|---|"
TOOLS=(splat tsdf open3d)
for s in $SCENES; do
  scene "$s"
  dir=$OUT/$s
  mkdir -p "$dir"
  declare -A BEST=() PEAK=()
  for ((k = 0; k < REPEAT; ++k)); do
    for t in "${TOOLS[@]}"; do
      run_tool "$t" "$dir"
      if better "$W" "${BEST[$t]:-}"; then BEST[$t]=$W; PEAK[$t]=$((R / 1024)); fi
    done
  done
  for t in "${TOOLS[@]}"; do
    if [ -n "$REF" ]; then
      "$BUILD/vdbrecon" eval "$dir/$t.ply" "$REF" --tau "$VOXEL" >"$dir/$t.json"
    else
      "$BUILD/vdbrecon" eval "$dir/$t.ply" "$dir/$t.ply" --samples 1000 >"$dir/$t.json"
    fi
    colour="-"
    if [ -n "$REF" ]; then colour=$(/usr/bin/python3 bench/paint.py "$dir/$t.ply" "$REF"); fi
    /usr/bin/python3 - "$dir/$t.json" "$s" "$t" "${BEST[$t]}" "${BEST[open3d]}" "${PEAK[$t]}" "$colour" "$REF" <<'PY'
import json, sys
e = json.load(open(sys.argv[1]))
r = e["recon"]
name = {"splat": "vdbrecon fuse", "tsdf": "vdbrecon fuse --fusion tsdf", "open3d": "Open3D ScalableTSDFVolume"}
quality = (f"{e['fscore'][0]['fscore']:.4f} | {e['chamfer_l1'] * 1e6:.0f}" if sys.argv[8] else "- | -")
print(f"| {sys.argv[2]} | {name[sys.argv[3]]} | {float(sys.argv[4]):.2f} | "
      f"{float(sys.argv[5]) / float(sys.argv[4]):.2f} | {sys.argv[6]} | {r['faces']} | {r['components']} | "
      f"{quality} | {sys.argv[7]} |")
PY
  done
  unset BEST PEAK
done
