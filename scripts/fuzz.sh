#!/usr/bin/env bash
# Fuzzes the point readers with libFuzzer (clang++-14, AddressSanitizer + UBSan):
#
#   scripts/fuzz.sh [SECONDS] [ply|xyz|obj|pcd ...]   run each target for SECONDS (default 60), in turn
#   scripts/fuzz.sh coverage [ply|xyz|obj|pcd ...]    line coverage of src/io*.cpp by the corpora
#
# One fuzzer at a time, one process, one core. Everything goes to fuzz/out/ (git-ignored): the
# build, the seeds (written by fuzz/make_seeds.cpp), each target's growing corpus, one log per
# run, and what a run finds (crashes, leaks, timeouts, out-of-memory) in crashes/<target>/.
# The exit status is 1 if anything was found: replay it with fuzz/out/build/fuzz_<target> FILE,
# fix it, and add the input to tests/test_bad_input.cpp as a regression test.
set -euo pipefail
cd "$(dirname "$0")/.."

mode=run
seconds=60
if [ "${1:-}" = coverage ]; then
  mode=coverage
  shift
elif [ -n "${1:-}" ]; then
  seconds=$1
  shift
fi
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(ply xyz obj pcd)

CXX=${FUZZ_CXX:-clang++-14}
command -v "$CXX" >/dev/null || { echo "fuzz: $CXX not found (apt-get install clang-14)" >&2; exit 2; }
out=fuzz/out

build() {  # build DIR [extra CXX flags]
  cmake -S fuzz -B "$1" -DCMAKE_CXX_COMPILER="$CXX" -DCMAKE_CXX_FLAGS="${2:-}" >/dev/null
  cmake --build "$1" -j"${JOBS:-1}"
}

build "$out/build"
rm -rf "$out/seeds"
"$out/build/make_seeds" "$out/seeds"

if [ "$mode" = coverage ]; then
  build "$out/build-cov" "-fprofile-instr-generate -fcoverage-mapping"
  rm -rf "$out/profiles"
  mkdir -p "$out/profiles"
  objects=()
  for t in "${targets[@]}"; do
    mkdir -p "$out/corpus/$t"
    LLVM_PROFILE_FILE="$out/profiles/$t.profraw" "$out/build-cov/fuzz_$t" -runs=0 \
      "$out/corpus/$t" "$out/seeds/$t" >/dev/null 2>&1
    objects+=(-object "$out/build-cov/fuzz_$t")
  done
  llvm-profdata-14 merge -sparse "$out"/profiles/*.profraw -o "$out/profiles/all.profdata"
  llvm-cov-14 report -instr-profile="$out/profiles/all.profdata" "${objects[@]:1}" \
    src/io.cpp src/io_ply.cpp src/io_text.cpp
  exit 0
fi

status=0
for t in "${targets[@]}"; do
  mkdir -p "$out/corpus/$t" "$out/crashes/$t"
  log="$out/$t.$(date +%Y%m%d-%H%M%S).log"
  echo "fuzz: $t for ${seconds} s (log: $log)"
  if ! "$out/build/fuzz_$t" "$out/corpus/$t" "$out/seeds/$t" -dict="fuzz/$t.dict" \
      -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -max_len=4096 -use_value_profile=1 \
      -artifact_prefix="$out/crashes/$t/" -print_final_stats=1 >"$log" 2>&1; then
    status=1
    echo "fuzz: $t FOUND A PROBLEM:"
    grep -E '^(==[0-9]+==ERROR|SUMMARY|.*runtime error|fuzz: broken|artifact_prefix|Test unit written)' "$log" || tail -30 "$log"
  fi
  # Executions, coverage (cov: edges, ft: features) and corpus size at the end of the run.
  grep -E '^#[0-9]+' "$log" | tail -1
  grep -E 'stat::number_of_executed_units|stat::peak_rss_mb' "$log" || true
done
exit $status
