#!/usr/bin/env bash
# Interleaved A/B timing of two vdbrecon binaries on the bunny scans (0.5 mm, --no-vdb): runs A
# and B alternately N times and prints, per binary, the best time of every stage (vdbrecon's
# log), its logged wall time and the whole process's wall time.
#   bench/ab.sh A_BIN B_BIN [N=5] [THREADS=2] [extra vdbrecon options...]
# e.g. build the starting commit in a worktree (cmake --build ../base/build --target vdbrecon_cli)
# and run bench/ab.sh ../base/build/vdbrecon build/vdbrecon 5 2
set -euo pipefail
cd "$(dirname "$0")/.."
A=$1 B=$2 N=${3:-5} T=${4:-2}
shift $(( $# < 4 ? $# : 4 ))
BUNNY=../shared/data/stanford_bunny/bun_scans_aligned.ply
[ -f "$BUNNY" ] || { echo "bench: $BUNNY not found (needs ../shared/data)"; exit 1; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for _ in $(seq "$N"); do
  for side in A B; do
    bin=$A; [ "$side" = B ] && bin=$B
    start=$(date +%s.%N)
    "$bin" "$BUNNY" --voxel 0.0005 --no-vdb --threads "$T" -o "$tmp/$side.ply" "$@" 2>&1 |
      grep "time:" | sed "s/^/$side /"
    echo "$side process $(echo "$(date +%s.%N) - $start" | bc)"
  done
done | /usr/bin/python3 -c '
import collections, re, sys
best = collections.defaultdict(dict)
for line in sys.stdin:
    side, rest = line.split(" ", 1)
    if rest.startswith("process"):
        v = float(rest.split()[1])
        best[side]["process"] = min(best[side].get("process", 9e9), v)
        continue
    for name, v in re.findall(r"([a-z() ]+?) ([0-9.]+) s", rest.split("time:")[1]):
        name = name.strip(", ")
        best[side][name] = min(best[side].get(name, 9e9), float(v))
for side in ("A", "B"):
    print(side, " ".join("%s %.3f" % kv for kv in best[side].items()))
'
