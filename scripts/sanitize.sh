#!/usr/bin/env bash
# Builds vdbrecon with AddressSanitizer + UndefinedBehaviorSanitizer (-DVDBRECON_SANITIZE=ON) in
# ../build-asan (or $BUILD) and runs the test suite under them: every ctest test except the
# Python one (an ASan-built extension would need libasan preloaded into python3).
#
#   scripts/sanitize.sh                 everything (about 15 min of tests on 2 cores)
#   scripts/sanitize.sh -R 'bad input'  a subset: extra arguments go to ctest
#
# Any sanitizer report fails the test that triggered it (halt_on_error). Leak checking is on.
set -euo pipefail
cd "$(dirname "$0")/.."
build=${BUILD:-../build-asan}

export ASAN_OPTIONS="halt_on_error=1:detect_leaks=1:check_initialization_order=1:strict_init_order=1:detect_stack_use_after_return=1"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"

cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DVDBRECON_SANITIZE=ON >/dev/null
cmake --build "$build" -j"${JOBS:-1}"
cd "$build"
ctest --output-on-failure -E '^python_tests$' -j"${CTEST_JOBS:-1}" "$@"
