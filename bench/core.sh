#!/usr/bin/env bash
# Core-pipeline benchmark (issue 2 bars): the Stanford bunny scans against the zippered mesh,
# plus the Kinect ghost-sheet check. Prints markdown rows for bench/RESULTS.md.
#   bench/core.sh [build-dir]        (needs ../shared/data; run scripts/setup.sh first)
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${1:-build}/vdbrecon
DATA=../shared/data
OUT=bench/out
mkdir -p "$OUT"
BUNNY=$DATA/stanford_bunny/bun_scans_aligned.ply
GT=$DATA/stanford_bunny/bun_zipper_gt.ply
[ -f "$BUNNY" ] || { echo "bench: $BUNNY not found (needs ../shared/data)"; exit 1; }

echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo), $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
echo "commit: $(git rev-parse --short HEAD 2>/dev/null || echo unknown)  date: $(date -u +%F)"
echo
echo "Wall time and stages: best of $REPEAT runs (seconds); the run writes the mesh and the .vdb."
echo
echo "| run | threads | wall s | peak RSS MB | read | normals | splat | mesh | write | vdb (during mesh) | faces | comps | F@0.5mm | F@1mm | Chamfer-L1 um | acc um | comp um |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
REPEAT=${REPEAT:-3}
run() {  # label threads args...   (best wall time of $REPEAT runs: this VM's timings are noisy)
  local label=$1 threads=$2; shift 2
  local log=$OUT/$label.$threads.log best=""
  for ((k = 0; k < REPEAT; ++k)); do
    /usr/bin/time -f "%e %M" -o "$OUT/time.txt" "$BIN" "$BUNNY" -o "$OUT/$label.ply" --threads "$threads" "$@" 2>"$OUT/try.log" >/dev/null
    read -r w r < "$OUT/time.txt"
    if [ -z "$best" ] || awk "BEGIN {exit !($w < $best)}"; then best=$w; wall=$w; rss=$r; cp "$OUT/try.log" "$log"; fi
  done
  local stages
  stages=$(/usr/bin/python3 -c 'import re,sys; t=dict((m[0].strip(), m[1]) for m in re.findall(r"([a-z ()]+) ([0-9.]+) s,", sys.stdin.read())); print("|".join(t.get(k, "-") for k in ["read", "normals", "splat", "mesh", "write", "vdb (during mesh)"]))' < "$log")
  "$BIN" eval "$OUT/$label.ply" "$GT" --tau 0.0005,0.001 > "$OUT/$label.json"
  /usr/bin/python3 - "$OUT/$label.json" "$label" "$threads" "$wall" "$((rss / 1024))" "$stages" <<'PY'
import json, sys
d = json.load(open(sys.argv[1])); f = d["fscore"]
print("| %s | %s | %s | %s | %s | %d | %d | %.4f | %.4f | %.1f | %.1f | %.1f |" % (
    sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5], sys.argv[6].replace("|", " | "),
    d["recon"]["faces"], d["recon"]["components"], f[0]["fscore"], f[1]["fscore"],
    d["chamfer_l1"] * 1e6, d["accuracy"] * 1e6, d["completeness"] * 1e6))
PY
}
run bunny-0.5mm 2 --voxel 0.0005
run bunny-0.5mm 1 --voxel 0.0005
run bunny-0.25mm 2 --voxel 0.00025
run bunny-0.5mm-estimate 2 --voxel 0.0005 --normals estimate

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
