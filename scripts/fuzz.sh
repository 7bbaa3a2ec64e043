#!/usr/bin/env bash
# Fuzzes the readers of hostile files with libFuzzer (clang++-14, AddressSanitizer + UBSan):
#
#   scripts/fuzz.sh [SECONDS] [TARGET ...]   run each target for SECONDS (default 60), in turn
#   scripts/fuzz.sh coverage [TARGET ...]    line coverage of the readers' sources by the corpora
#
# Targets (fuzz/CMakeLists.txt; all of them when none is named):
#   ply xyz obj pcd las                       point files, read from memory
#   depth_png depth_exr                       depth images (read_depth_image)
#   color_png color_jpg                       colour images (read_color_image)
#   transforms                                transforms.json (read_scene)
#   layouts                                   dataset folders: TUM, 7-Scenes, Redwood, ScanNet,
#                                             Replica, KITTI (with its .bin scans), scan sensors,
#                                             organized PCD
#
# One fuzzer at a time, one process, one core. Everything goes to fuzz/out/ (git-ignored): the
# build, the seeds (written by fuzz/make_seeds.cpp), each target's growing corpus, one log per
# run, and what a run finds (crashes, leaks, timeouts, out-of-memory, an allocation above
# 256 MB) in crashes/<target>/. The exit status is 1 if anything was found: replay it with
# fuzz/out/build/fuzz_<target> FILE, fix it, and add the input to tests/test_bad_input.cpp as a
# regression test. A target's dictionary is fuzz/<target>.dict, else that of its format
# (depth_png and color_png share png.dict).
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
[ ${#targets[@]} -gt 0 ] ||
  targets=(ply xyz obj pcd las depth_png depth_exr color_png color_jpg transforms layouts)

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
    src/io.cpp src/io_ply.cpp src/io_text.cpp src/io_pcd.cpp src/io_las.cpp src/io_depth.cpp \
    src/io_color.cpp src/scene.cpp src/scene_layouts.cpp src/camera.cpp
  exit 0
fi

status=0
for t in "${targets[@]}"; do
  mkdir -p "$out/corpus/$t" "$out/crashes/$t"
  log="$out/$t.$(date +%Y%m%d-%H%M%S).log"
  echo "fuzz: $t for ${seconds} s (log: $log)"
  dict=fuzz/$t.dict
  [ -f "$dict" ] || dict=fuzz/${t#*_}.dict
  if ! "$out/build/fuzz_$t" "$out/corpus/$t" "$out/seeds/$t" -dict="$dict" \
      -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -malloc_limit_mb=256 \
      -max_len=4096 -use_value_profile=1 \
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
