#!/usr/bin/env bash
# One command: install what is missing, build, and reconstruct the sample scan in data/.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh
mkdir -p out
echo
echo "demo: reconstructing data/bunny_sample.ply (72,455 points of the Stanford bunny scans)"
./build/vdbrecon data/bunny_sample.ply -o out/bunny_sample.ply --preview out/bunny_sample.png
echo
echo "demo: the mesh is out/bunny_sample.ply and the volume (sdf, weight, density, nearest grids)"
echo "      is out/bunny_sample.splat.vdb; open either in Blender, Houdini or MeshLab."
echo "      out/bunny_sample.png is a shaded picture of the mesh."
