#!/usr/bin/env bash
# In-process mesher timing (bench/meshers_inprocess.cpp) on the bunny scans at --voxel 0.0005:
# splats the volume once (with $BIN, default build/vdbrecon; kept in bench/out), then meshes it with dual, vdb, mc and dc at 1 and 2
# threads, mesher alone and whole mesh stage, with the library of each build directory given.
# With two build directories the runs alternate (A, B, A, B, ...; 3 rounds of best-of-N), for an
# A/B comparison on a busy machine. Prints the best time of each over all rounds.
#   bench/meshers_inprocess.sh [N=7] BUILD [BUILD2]      e.g. bench/meshers_inprocess.sh 7 ../base/build build
set -euo pipefail
cd "$(dirname "$0")/.."
N=${1:-7}
shift || true
BUILDS=("${@:-build}")
OUT=bench/out
source bench/common.sh
VOL=$OUT/meshers_inprocess.splat.vdb
[ -f "$VOL" ] || "${BIN:-build/vdbrecon}" "$BUNNY" --voxel 0.0005 -q -o "$OUT/meshers_inprocess.ply" >/dev/null
exe() { echo "$OUT/meshers_inprocess.$(echo "$1" | tr '/.' '__')"; }
for b in "${BUILDS[@]}"; do
  # The harness includes the internal headers of the sources the build came from.
  src=$(sed -n 's/^CMAKE_HOME_DIRECTORY:INTERNAL=//p' "$b/CMakeCache.txt")
  g++ -O3 -DNDEBUG -std=c++17 -DOPENVDB_ABI_VERSION_NUMBER=10 -DOPENVDB_USE_DELAYED_LOADING \
    -I"$src/include" -I"$src/src" -isystem /usr/include/Imath bench/meshers_inprocess.cpp \
    "$b/libvdbrecon.a" -lopenvdb -ltbb -lImath-3_1 -lOpenEXR-3_1 -lz -llz4 -lpthread -o "$(exe "$b")"
done
# The heap the CLI has where huge pages help (apps/huge_pages.h); the rounds run back to back.
export GLIBC_TUNABLES=glibc.malloc.hugetlb=1:glibc.malloc.top_pad=$((64 << 20))
machine_line
echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg); best of 3 x $N runs, seconds"
for round in 1 2 3; do
  for b in "${BUILDS[@]}"; do
    "$(exe "$b")" "$VOL" "$N" | sed "s|^|$b |"
  done
done | /usr/bin/python3 -c '
import sys
best = {}
for line in sys.stdin:
    build, mesher, threads, m, s, faces = line.split()
    k = (build, mesher, threads)
    old = best.get(k, (9e9, 9e9, faces))
    best[k] = (min(old[0], float(m)), min(old[1], float(s)), faces)
print()
print("| build | mesher | threads | mesher s | mesh stage s | faces |")
print("|---|---|---|---|---|---|")
for (build, mesher, threads), (m, s, faces) in sorted(best.items(), key=lambda kv: (kv[0][2], kv[0][1], kv[0][0])):
    print("| %s | %s | %s | %.4f | %.4f | %s |" % (build, mesher, threads, m, s, faces))
'
