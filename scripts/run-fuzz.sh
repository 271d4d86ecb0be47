#!/usr/bin/env bash
# Builds the libFuzzer targets of tests/fuzz (clang, -fsanitize=fuzzer,address,undefined; the
# separate configuration PLANESDF_FUZZ=ON in build-fuzz/) and runs them:
#   1. each target for a bounded time (default 30 s, -max_total_time), starting from its seed
#      corpus tests/fuzz/corpus/<target>/; inputs it finds go to build-fuzz/fuzz-corpus/<target>/;
#   2. each target once over its seeds, tests/fuzz/regressions/<target>/ and the generated
#      reproducers of issue 27 (JSON nested 100,000 deep, see generate_regressions below).
# Any crash, sanitizer report, uncaught exception other than planesdf::Error, timeout (10 s per
# input) or allocation over 2 GB is a finding: its input is kept as
# build-fuzz/fuzz-findings/<target>-crash-* (or -timeout-*, -oom-*) and the script exits 1.
# Usage: bash scripts/run-fuzz.sh [SECONDS_PER_TARGET] [TARGET...]   (scripts/run-tests.sh calls it)
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=$(nproc 2>/dev/null || echo 2)
seconds=${1:-30}
[ $# -gt 0 ] && shift
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=(ply pcd lzf tum depth_png psdf config scene events changes)
build=build-fuzz
cc=${CC_FUZZ:-clang-14}
cxx=${CXX_FUZZ:-clang++-14}

step() { printf '\n=== fuzz: %s (%ds)\n' "$*" "$SECONDS" >&2; }

step "build ($cxx, PLANESDF_FUZZ=ON)"
CC=$cc CXX=$cxx cmake -S . -B "$build" -DPLANESDF_FUZZ=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build "$build" -j"$jobs" --target "${targets[@]/#/fuzz_}"

# Little-endian u32 / u64 as bytes, for the generated .psdf.
le32() { printf "$(printf '\\x%02x\\x%02x\\x%02x\\x%02x' $(($1 & 255)) $(($1 >> 8 & 255)) \
  $(($1 >> 16 & 255)) $(($1 >> 24 & 255)))"; }
le64() { le32 $(($1 & 0xffffffff)); le32 $(($1 >> 32)); }
nested() { head -c "$1" /dev/zero | tr '\0' '['; head -c "$1" /dev/zero | tr '\0' ']'; }

# The crash reproducers of issue 27 that are too large to keep in the repository.
generate_regressions() {
  local out=$1
  rm -rf "$out"
  mkdir -p "$out"/{config,scene,psdf}
  nested 100000 >"$out/config/nested_100000_arrays.json"
  { printf '{"up": '; nested 100000; printf '}'; } >"$out/config/nested_100000_in_key.json"
  nested 100000 >"$out/scene/nested_100000_arrays.json"
  { printf '{"objects": '; nested 100000; printf '}'; } >"$out/scene/nested_100000_in_key.json"
  psdf_with_config "$(nested 100000)" >"$out/psdf/embedded_config_nested_100000.psdf"
  psdf_with_config '{"threads": 100000}' >"$out/psdf/embedded_config_threads_100000.psdf"
}

# A version-2 map holding only the config text $1: header, config, zero frames, no up, no
# planes, no points and a zero checksum (fuzz_psdf also reads it with the checksum fixed).
psdf_with_config() {
  local cfg=${#1}
  printf 'PSDFMAP\0'
  le32 2; le32 0; le64 $((4 + cfg + 8 + 1 + 24 + 4 + 8))
  le32 "$cfg"; printf '%s' "$1"
  le64 0; printf '\0'; head -c 24 /dev/zero; le32 0; le64 0
  le64 0
}

# The TUM and depth PNG targets write each input to a scratch file: keep those in memory.
if [ -d /dev/shm ] && [ -w /dev/shm ]; then export TMPDIR=/dev/shm; fi

findings=$build/fuzz-findings
rm -rf "$findings"
mkdir -p "$findings"
failed=()

for t in "${targets[@]}"; do
  step "$t for ${seconds}s"
  work=$build/fuzz-corpus/$t
  log=$build/fuzz-logs/$t.log
  mkdir -p "$work" "$build/fuzz-logs"
  if "$build/bin/fuzz_$t" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 \
      -print_final_stats=1 -artifact_prefix="$findings/$t-" "$work" "tests/fuzz/corpus/$t" \
      2>"$log"; then
    grep -E '^(#[0-9]+ +DONE|stat::number_of_executed_units|stat::average_exec_per_sec)' "$log" >&2 || true
  else
    tail -n 60 "$log" >&2
    failed+=("$t (fuzzing)")
  fi
done

generate_regressions "$build/fuzz-regressions"
for t in "${targets[@]}"; do
  step "$t over its seeds and regression inputs"
  mapfile -t inputs < <(find "tests/fuzz/corpus/$t" "tests/fuzz/regressions/$t" \
    "$build/fuzz-regressions/$t" -type f 2>/dev/null | sort)
  log=$build/fuzz-logs/$t.regressions.log
  if "$build/bin/fuzz_$t" -timeout=10 -rss_limit_mb=2048 -artifact_prefix="$findings/$t-" \
      "${inputs[@]}" 2>"$log"; then
    echo "${#inputs[@]} inputs passed" >&2
  else
    tail -n 60 "$log" >&2
    failed+=("$t (regressions)")
  fi
done

if [ ${#failed[@]} -gt 0 ]; then
  printf 'run-fuzz: findings in %s; inputs in %s\n' "${failed[*]}" "$findings" >&2
  exit 1
fi
step "no findings"
