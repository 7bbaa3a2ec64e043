#!/usr/bin/env bash
# kNN benchmark (bench/knn.cpp): KnnIndex's backends -- our Morton grid, FLANN's exact kd-tree,
# FLANN's eps-approximate search -- on the bunny scans, the room scan,
# synthetic clouds and a large synthetic terrain; time and exactness against brute force, on 1
# and 2 threads.
#   bench/knn.sh [build-dir] [large-millions=20]   (needs ../shared/data; run scripts/setup.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build}
LARGE=${2:-20}
OUT=bench/out
source bench/common.sh
mkdir -p bench/out
g++ -O3 -DNDEBUG -std=c++17 -DOPENVDB_ABI_VERSION_NUMBER=10 -Iinclude -isystem /usr/include/Imath \
  bench/knn.cpp "$BUILD/libvdbrecon.a" -lopenvdb -ltbb -llz4 -lImath-3_1 -lOpenEXR-3_1 -lpng -lz \
  -lpthread -o bench/out/knn
machine_line
for t in 2 1; do
  echo
  echo "threads: $t"
  echo
  if [ "$t" = 2 ]; then
    bench/out/knn "$BUNNY" "$DATA/pcl_laser/room_scan1.ply" "$t" "$LARGE"
  else
    bench/out/knn "$BUNNY" "$DATA/pcl_laser/room_scan1.ply" "$t"
  fi
done
