#!/usr/bin/env bash
# Planar regions (--planes) on the room laser scan (voxel 0.1 m, as the MANIFEST suggests), the
# table scene (Kinect stereo, 5 mm), the Redwood living-room fragment (1 cm) and the Autzen
# LiDAR tile (4.4 ft): faces, regions, boundary edges and pieces with and without --planes, the
# stage's time, how far the planar mesh lies from the mesh it was made from (`vdbrecon eval`:
# the plain mesh's samples against the planar one, within 0.25 and 0.5 voxel, Hausdorff), and
# the share of the large planar regions' points within 0.5 voxel of it, all together and in
# the worst region (bench/planes_points.py).
#   bench/planes.sh [build-dir]   (needs ../shared/data; run scripts/setup.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build}
BIN=$BUILD/vdbrecon
OUT=bench/out/planes
source bench/common.sh
machine_line

# case LABEL INPUT VOXEL ARGS...
case_row() {
  local label=$1 input=$2 voxel=$3; shift 3
  "$BIN" "$input" -o "$OUT/$label.plain.ply" --voxel "$voxel" --no-vdb "$@" 2>"$OUT/$label.plain.log" >/dev/null
  "$BIN" "$input" -o "$OUT/$label.planes.ply" --voxel "$voxel" --no-vdb --planes "$@" 2>"$OUT/$label.planes.log" >/dev/null
  "$BIN" eval "$OUT/$label.plain.ply" "$OUT/$label.planes.ply" \
    --tau "$(awk -v v="$voxel" 'BEGIN {print 0.25 * v "," 0.5 * v}')" > "$OUT/$label.json"
  PYTHONPATH="$BUILD/python${PYTHONPATH:+:$PYTHONPATH}" /usr/bin/python3 - "$OUT/$label" "$voxel" "$*" "$input" <<'PY'
import json, re, sys
import numpy as np
sys.path.insert(0, "bench")
import planes_points, vdbrecon
base, voxel, args, scan = sys.argv[1], float(sys.argv[2]), sys.argv[3], sys.argv[4]
def topo(log):
    t = open(log).read()
    faces = re.search(r"mesh: \d+ vertices, (\d+) triangles", t).group(1)
    return t, faces
plain, fp = topo(base + ".plain.log")
planes, _ = topo(base + ".planes.log")
m = re.search(r"planes: (\d+) planar regions \((\d+) of (\d+) faces\).*?; (\d+) -> (\d+) faces", planes)
stage = re.search(r"planes ([0-9.]+) s", planes).group(1)
e = json.load(open(base + ".json"))
rec, ref = e["recon"], e["reference"]
f = {round(x["tau"] / voxel, 2): x for x in e["fscore"]}
points = np.asarray(vdbrecon.read_points(scan).cloud.positions)
ours, label, count = planes_points.region_points(points, vdbrecon.read_mesh(base + ".plain.ply"), voxel)
_, within, worst, _ = planes_points.coverage(vdbrecon.read_mesh(base + ".planes.ply"), ours, label, count, voxel)
print(f"| {base.split('/')[-1]} {args} | {m.group(3)} | {m.group(1)} ({int(m.group(2)) * 100 // int(m.group(3))} % of faces) "
      f"| {m.group(5)} ({int(m.group(3)) / int(m.group(5)):.1f}x fewer) | {ref['boundary_edges']} / {ref['components']} "
      f"(plain {rec['boundary_edges']} / {rec['components']}) | {stage} "
      f"| {f[0.25]['precision']:.4f} / {f[0.5]['precision']:.4f} | {e['hausdorff'] / voxel:.2f} "
      f"| {within:.4f} / {worst:.4f} |")
PY
}

echo
echo "| scan | faces | planar regions | faces with --planes | boundary edges / pieces | stage s | plain mesh within 0.25 / 0.5 voxel | Hausdorff, voxels | region points within 0.5 voxel: all / worst region |"
echo "|---|---|---|---|---|---|---|---|---|"
case_row room "$DATA/pcl_laser/room_scan1.ply" 0.1
case_row table "$DATA/pcl_kinect/table_scene_mug_stereo_textured.ply" 0.005
case_row room-dc "$DATA/pcl_laser/room_scan1.ply" 0.1 --mesher dc
case_row fragment "$DATA/redwood_livingroom/fragment.ply" 0.01
case_row autzen "$DATA/pdal_autzen/autzen_trim.ply" 4.4
