#!/usr/bin/env bash
# Core-pipeline benchmark (issue 2 bars): the Stanford bunny scans against the zippered mesh,
# plus the Kinect ghost-sheet check. Prints markdown rows for bench/RESULTS.md.
#   bench/core.sh [build-dir]        (needs ../shared/data; run scripts/setup.sh first)
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${1:-build}/vdbrecon
OUT=bench/out
source bench/common.sh

machine_line
echo
echo "Wall time and stages: best of $REPEAT runs (seconds); the run writes the mesh and the .vdb."
echo
echo "| run | threads | wall s | peak RSS MB | read | outliers | normals | splat | mesh | clean | write | vdb (in the background) | faces | comps | F@0.5mm | F@1mm | Chamfer-L1 um | acc um | comp um |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
row() {  # label threads args...
  local label=$1 threads=$2
  run "$@"
  /usr/bin/python3 - "$OUT/$label.json" "$label" "$threads" "$WALL" "$RSS" \
    "$(stage_times "$OUT/$label.$threads.log" read outliers normals splat mesh clean write "vdb (in the background)")" <<'PY'
import json, sys
d = json.load(open(sys.argv[1])); f = d["fscore"]
print("| %s | %s | %s | %s | %s | %d | %d | %.4f | %.4f | %.1f | %.1f | %.1f |" % (
    sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5], sys.argv[6].replace("|", " | "),
    d["recon"]["faces"], d["recon"]["components"], f[0]["fscore"], f[1]["fscore"],
    d["chamfer_l1"] * 1e6, d["accuracy"] * 1e6, d["completeness"] * 1e6))
PY
}
row bunny-0.5mm 2 --voxel 0.0005
row bunny-0.5mm 1 --voxel 0.0005
row bunny-0.25mm 2 --voxel 0.00025
row bunny-0.5mm-estimate 2 --voxel 0.0005 --normals estimate

echo
echo "Peak memory (process peak so far) at the end of each stage:"
for f in "$OUT"/*.log; do
  case "$f" in *try.log|*kinect.log) continue ;; esac
  echo "    $(basename "$f" .log): $(grep -h "peak memory after" "$f" | sed 's/.*after: //')"
done
echo
echo "Kinect frame (auto voxel, --viewpoint 0,0,0):"
KIN=$DATA/pcl_kinect/capture0001.ply
"$BIN" "$KIN" --viewpoint 0,0,0 -o "$OUT/kinect.ply" --no-vdb 2>"$OUT/kinect.log" >/dev/null
grep -E "voxel|time:" "$OUT/kinect.log" | sed 's/^/    /'
