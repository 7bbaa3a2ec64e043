#!/usr/bin/env bash
# Mesher benchmark (issue 3): the bunny scans at --voxel 0.0005 meshed by volumeToMesh (vdb), our
# marching cubes (mc) and our dual contouring (dc); mesh-stage time, faces, topology and the
# F-score against the zippered reference. Prints a markdown table for bench/RESULTS.md.
#   bench/meshers.sh [build-dir]        (needs ../shared/data; run scripts/setup.sh first)
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${1:-build}/vdbrecon
OUT=bench/out
source bench/common.sh

machine_line
echo
echo "Bunny scans, --voxel 0.0005, --no-vdb; best of $REPEAT runs; times in seconds."
echo
echo "| mesher | threads | mesh stage s | wall s | peak RSS MB | faces | comps | boundary edges | non-manifold edges | F@0.5mm | F@1mm | Chamfer-L1 um |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
for threads in 2 1; do
  for m in vdb mc dc; do
    run "mesher-$m" "$threads" --voxel 0.0005 --no-vdb --mesher "$m"
    /usr/bin/python3 - "$OUT/mesher-$m.json" "$m" "$threads" "$(stage_times "$OUT/mesher-$m.$threads.log" mesh)" "$WALL" "$RSS" <<'PY'
import json, sys
d = json.load(open(sys.argv[1])); f = d["fscore"]; t = d["recon"]
print("| %s | %s | %s | %s | %s | %d | %d | %d | %d | %.4f | %.4f | %.1f |" % (
    sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5], sys.argv[6], t["faces"], t["components"],
    t["boundary_edges"], t["nonmanifold_edges"], f[0]["fscore"], f[1]["fscore"], d["chamfer_l1"] * 1e6))
PY
  done
done
