#!/usr/bin/env bash
# Measures the machine's memory bandwidth (bench/bandwidth.cpp, STREAM-style copy and triad on 1
# and 2 threads), for the splat's memory-bound estimate in bench/RESULTS.md.
#   bench/bandwidth.sh
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p bench/out
g++ -O2 -march=native -std=c++17 bench/bandwidth.cpp -o bench/out/bandwidth -ltbb
echo "machine: $(nproc) cores, $(free -g | awk '/^Mem:/ {print $2}') GiB, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ *//')"
bench/out/bandwidth
