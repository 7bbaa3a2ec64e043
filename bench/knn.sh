#!/usr/bin/env bash
# kNN benchmark (bench/knn.cpp): vdbrecon's Morton-grid kNN against FLANN's kd-tree, exactness
# and time, on 1 and 2 threads. Installs FLANN's headers (libflann-dev, liblz4-dev) if missing:
# vdbrecon itself no longer needs them.
#   bench/knn.sh [build-dir]        (needs ../shared/data; run scripts/setup.sh first)
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build}
BIN=$BUILD/vdbrecon
OUT=bench/out
source bench/common.sh
for p in libflann-dev liblz4-dev; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || {
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$p" >/dev/null; }
done
mkdir -p bench/out
g++ -O3 -DNDEBUG -std=c++17 -DOPENVDB_ABI_VERSION_NUMBER=10 -Iinclude -isystem /usr/include/Imath \
  bench/knn.cpp "$BUILD/libvdbrecon.a" -lopenvdb -ltbb -llz4 -lImath-3_1 -lOpenEXR-3_1 -lz \
  -lpthread -o bench/out/knn
machine_line
for t in 1 2; do
  echo
  echo "threads: $t"
  echo
  bench/out/knn "$BUNNY" "$t"
done
