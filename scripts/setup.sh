#!/usr/bin/env bash
# Installs the Debian 12 packages vdbrecon needs (only the missing ones), then configures and
# builds it in ./build (Release). Used by demo.sh and test.sh; safe to run repeatedly.
set -euo pipefail
cd "$(dirname "$0")/.."

PACKAGES=(
  cmake g++ make ccache
  help2man                                # the man page, from --help
  libopenvdb-dev libboost-iostreams-dev   # OpenVDB 10; FindOpenVDB needs boost_iostreams
  libtbb-dev libeigen3-dev
  libopenexr-dev zlib1g-dev               # --preview pictures: .exr (with depth), .png
  libpng-dev nlohmann-json3-dev           # fuse: 16-bit PNG depth, transforms.json
  libjpeg-dev                             # fuse: JPEG colour images (libjpeg-turbo)
  libflann-dev liblz4-dev                 # --knn flann: FLANN's kd-trees
  catch2                                  # Catch2 v2 tests
  pybind11-dev python3-dev python3-numpy  # the Python module (built for /usr/bin/python3)
  python3-pytest                          # its tests
  python3-distributed                     # vdbrecon.distributed: the tiles as Dask tasks
  python3-openvdb libopenvdb-tools        # interop tests: pyopenvdb, vdb_print
  blender                                 # interop test: Blender imports and renders the .vdb
)

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}"
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

JOBS=${JOBS:-$(nproc)}
if ((JOBS > 2)); then JOBS=2; fi   # OpenVDB translation units take ~2 GB each to compile
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DVDBRECON_BUILD_PYTHON=ON \
  -DPython3_EXECUTABLE=/usr/bin/python3 >/dev/null
cmake --build build -j"$JOBS"
