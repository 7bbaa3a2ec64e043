#!/usr/bin/env bash
# Interop check with pyopenvdb, vdb_print and Blender (see interop_check.py). Run from anywhere:
#   python/tools/interop_check.sh [BUILD_DIR (default build)] [OUT_DIR (default out/interop)]
set -euo pipefail
cd "$(dirname "$0")/../.."
build=${1:-build}
out=${2:-out/interop}
PYTHONPATH="$build/python" exec /usr/bin/python3 python/tools/interop_check.py \
  --cli "$build/vdbrecon" --out "$out"
