#!/usr/bin/env bash
# Builds planesdf and runs every test, as CI does (.ci/run calls this script):
#   1. Release build with warnings as errors; all tests (unit, adapter, end-to-end on ../shared).
#   2. Install into a prefix and build + run an out-of-tree find_package(planesdf) consumer.
#   3. AddressSanitizer + UndefinedBehaviorSanitizer build; the unit tests; the worker pool's
#      tests under ThreadSanitizer.
#   4. The libFuzzer targets (clang, ASan + UBSan), 30 s each, then their regression inputs
#      (scripts/run-fuzz.sh).
# Usage: bash scripts/run-tests.sh [--no-sanitizers]
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
jobs=$(nproc 2>/dev/null || echo 2)
sanitizers=1
[ "${1:-}" = "--no-sanitizers" ] && sanitizers=0

step() { printf '\n=== %s (%ds)\n' "$*" "$SECONDS" >&2; }

step "dependencies"
bash scripts/install-deps.sh

step "release build"
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DPLANESDF_WERROR=ON >/dev/null
cmake --build build -j"$jobs"

step "release tests"
ctest --test-dir build --output-on-failure -j"$jobs" --timeout 600

step "install + out-of-tree consumer"
rm -rf build/_install build/_consumer
cmake --install build --prefix build/_install >/dev/null
# -march=native: the installed target must give the consumer the library's Eigen layout.
cmake -S tests/consumer -B build/_consumer -DCMAKE_PREFIX_PATH="$root/build/_install" \
  -DCMAKE_CXX_FLAGS="-march=native" >/dev/null
cmake --build build/_consumer -j"$jobs" >/dev/null
build/_consumer/consumer
build/_install/bin/planesdf --version  # the installed CLI finds its libraries (RUNPATH)
build/_install/bin/slam_loop >/dev/null

if [ "$sanitizers" = 1 ]; then
  step "address + undefined sanitizer build"
  # Line tables only (-g1): enough for the sanitizers' stack traces, and a much faster build.
  cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPLANESDF_SANITIZE=address,undefined \
    -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG" \
    -DPLANESDF_BUILD_APPS=OFF -DPLANESDF_BUILD_BENCH=OFF -DPLANESDF_BUILD_EXAMPLES=OFF >/dev/null
  # Only what `ctest -L unit` runs: the end-to-end tests are not run under the sanitizers.
  cmake --build build-asan -j"$jobs" --target planesdf_unit_tests planesdf_mrpt_tests \
    planesdf_octomap_tests
  step "sanitizer unit tests"
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
    ctest --test-dir build-asan -L unit --output-on-failure -j"$jobs" --timeout 900
  step "thread sanitizer: the worker pool"
  # The pool's synchronisation (src/parallel.cpp) under TSan, through its own tests (TSan's
  # runtime thread takes CPU time, so the idle-CPU test is left to the builds above).
  g++ -std=c++17 -O1 -g -fsanitize=thread -Isrc src/parallel.cpp tests/unit/parallel_test.cpp \
    -lgtest -lgtest_main -pthread -o build-asan/parallel_tsan
  TSAN_OPTIONS=halt_on_error=1 build-asan/parallel_tsan --gtest_repeat=10 \
    --gtest_filter=-ParallelTest.IdleWorkersSleep >/dev/null
  step "fuzz targets (scripts/run-fuzz.sh)"
  bash scripts/run-fuzz.sh 30
fi
step "all tests passed"
