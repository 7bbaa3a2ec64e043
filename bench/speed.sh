#!/usr/bin/env bash
# Issue 48's headline in one invocation, so that the ratios are taken on the same machine state:
# the bunny scans at 0.5 mm (the default run: mesh and .vdb written) at 2 and 1 threads, best
# of $REPEAT each, and Open3D's screened Poisson at depth 10 (bench/peers.py, every core, best
# of $POISSON_REPEAT), each scored against the zippered reference. Prints the times, the
# vdbrecon / Poisson ratio and the 1 -> 2 thread gain of the whole process.
#   bench/speed.sh [build-dir]     (needs ../shared/data; installs python3-open3d if missing)
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${1:-build}/vdbrecon
OUT=bench/out/speed
source bench/harness.sh  # and bench/common.sh
ensure_packages time python3-open3d
POISSON_REPEAT=${POISSON_REPEAT:-2}

machine_line
load_line
echo
run speed 2 --voxel 0.0005
w2=$WALL rss2=$RSS
stages2=$(stage_times "$OUT/speed.2.log" read outliers normals splat mesh clean "vdb (in the background)")
run speed 1 --voxel 0.0005
w1=$WALL
stages1=$(stage_times "$OUT/speed.1.log" read outliers normals splat mesh clean "vdb (in the background)")

best=""
for ((k = 0; k < POISSON_REPEAT; ++k)); do
  /usr/bin/time -f "%e" -o "$OUT/time.txt" /usr/bin/python3 bench/peers.py poisson "$BUNNY" \
    "$OUT/poisson.ply" --depth 10 --trim 0.01 >/dev/null 2>"$OUT/poisson.log"
  w=$(tail -n 1 "$OUT/time.txt")
  if better "$w" "$best"; then best=$w; fi
done
"$BIN" eval "$OUT/poisson.ply" "$GT" --tau 0.0005,0.001 > "$OUT/poisson.json"

/usr/bin/python3 - "$OUT" "$w2" "$w1" "$best" "$rss2" "$stages2" "$stages1" <<'PY'
import json, sys
out, w2, w1, wp, rss2, s2, s1 = sys.argv[1:]
w2, w1, wp = float(w2), float(w1), float(wp)
def row(label, wall, j, extra):
    d = json.load(open(j))
    f = d["fscore"]
    print("| %s | %.2f | %.4f | %.4f | %.1f | %s |" % (label, wall, f[0]["fscore"], f[1]["fscore"],
                                                     d["chamfer_l1"] * 1e6, extra))
print("| run | wall s | F@0.5mm | F@1mm | Chamfer-L1 um | stages: read, outliers, normals, splat, mesh, clean, vdb |")
print("|---|---|---|---|---|---|")
row("vdbrecon 0.5 mm, 2 threads", w2, out + "/speed.json", s2.replace("|", ", ") + "; peak " + rss2 + " MB")
row("vdbrecon 0.5 mm, 1 thread", w1, out + "/speed.json", s1.replace("|", ", "))
row("Open3D Poisson depth 10, trim 1 %", wp, out + "/poisson.json", "")
print()
print("vdbrecon (2 threads) vs Open3D Poisson depth 10: %.1fx; vdbrecon 1 -> 2 threads: %.2fx"
      % (wp / w2, w1 / w2))
PY
