#!/usr/bin/env bash
# Mesher benchmark (issue 3): the bunny scans at --voxel 0.0005 meshed by our dual marching cubes
# (dual, the default), volumeToMesh (vdb), our marching cubes (mc) and our dual contouring (dc);
# mesh-stage time, faces, topology and the F-score against the zippered reference. Prints a markdown table for bench/RESULTS.md.
#   bench/meshers.sh [build-dir]        (needs ../shared/data; run scripts/setup.sh first)
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${1:-build}/vdbrecon
OUT=bench/out
source bench/common.sh

machine_line
echo
echo "Bunny scans, --voxel 0.0005, --no-vdb; times in seconds. The meshers take turns (dual, vdb,"
echo "mc, dc, dual, ...; $REPEAT rounds per thread count), and each row is its run with the fastest"
echo "mesh stage, so a slow spell of the VM does not fall on one mesher only."
echo
echo "| mesher | threads | mesh stage s | wall s | peak RSS MB | faces | comps | boundary edges | non-manifold edges | F@0.5mm | F@1mm | Chamfer-L1 um |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
declare -A best wall rss
for threads in 2 1; do
  for ((k = 0; k < REPEAT; ++k)); do
    for m in dual vdb mc dc; do
      /usr/bin/time -f "%e %M" -o "$OUT/time.txt" "$BIN" "$BUNNY" -o "$OUT/mesher-$m.ply" \
        --threads "$threads" --voxel 0.0005 --no-vdb --mesher "$m" 2>"$OUT/try.log" >/dev/null
      read -r w r <"$OUT/time.txt"
      t=$(stage_times "$OUT/try.log" mesh)
      key=$m.$threads
      if better "$t" "${best[$key]:-}"; then
        best[$key]=$t
        wall[$key]=$w
        rss[$key]=$((r / 1024))
        cp "$OUT/try.log" "$OUT/mesher-$m.$threads.log"
      fi
    done
  done
  for m in dual vdb mc dc; do
    key=$m.$threads
    # The meshes do not depend on the thread count: scored once.
    [ "$threads" = 2 ] && "$BIN" eval "$OUT/mesher-$m.ply" "$GT" --tau 0.0005,0.001 >"$OUT/mesher-$m.json"
    /usr/bin/python3 - "$OUT/mesher-$m.json" "$m" "$threads" "${best[$key]}" "${wall[$key]}" "${rss[$key]}" <<'PY'
import json, sys
d = json.load(open(sys.argv[1])); f = d["fscore"]; t = d["recon"]
print("| %s | %s | %s | %s | %s | %d | %d | %d | %d | %.4f | %.4f | %.1f |" % (
    sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5], sys.argv[6], t["faces"], t["components"],
    t["boundary_edges"], t["nonmanifold_edges"], f[0]["fscore"], f[1]["fscore"], d["chamfer_l1"] * 1e6))
PY
  done
done
