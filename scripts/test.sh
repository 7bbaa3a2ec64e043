#!/usr/bin/env bash
# One command: install what is missing, build, and run every test (ctest). The tests that need
# the real scans in ../shared/data say SKIPPED when it is absent (a user's clone).
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh
cd build
ctest --output-on-failure -j"${JOBS:-2}"
