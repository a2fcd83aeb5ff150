#!/usr/bin/env bash
# libFuzzer targets (tests/fuzz), built with Debian's clang into ./build-fuzz (ASan + UBSan).
#   scripts/fuzz.sh TARGET SECONDS [libFuzzer options...]
#       fuzzes one target (frame_decoder, server_config, urdf, mesh, session) for SECONDS on
#       its working corpus build-fuzz/corpus/TARGET, seeded from tests/fuzz/corpus/TARGET;
#       crashes, leaks and timeouts are written to build-fuzz/crashes/TARGET/.
#   scripts/fuzz.sh --smoke [SECONDS]
#       what scripts/test.sh runs: every target over its seeds and kept reproducers, then
#       mutations for SECONDS (default 20) each, from a fixed seed; fails on any crash, leak,
#       timeout or sanitizer report.
#   scripts/fuzz.sh --replay TARGET
#       runs the ASan + UBSan build once over TARGET's working corpus, seeds and reproducers,
#       leak checks on: what a run under other sanitizers found is checked for memory errors.
#   scripts/fuzz.sh --build
#   FUZZ_SANITIZE=undefined scripts/fuzz.sh TARGET SECONDS ...
#       the same run built without ASan into build-fuzz-undefined (same corpus and crash
#       folders): for targets whose inputs ASan slows most (mesh: assimp's OBJ reader zeroes a
#       4 MB buffer per file, which ASan maps afresh each time: 326 against 6,900 runs/s).
#       Memory errors that do not crash and leaks go unseen there: follow it with --replay.
set -euo pipefail
cd "$(dirname "$0")/.."
TARGETS=(frame_decoder server_config urdf mesh session)
sanitize=${FUZZ_SANITIZE:-address,undefined}
case $sanitize in
  address,undefined) dir=build-fuzz ;;
  undefined) dir=build-fuzz-undefined ;;
  *) echo "arref: FUZZ_SANITIZE is address,undefined (default) or undefined, not '$sanitize'" >&2; exit 2 ;;
esac
store=build-fuzz  # corpus and crash folders, whichever build runs

# Builds every target, or the one named.
build() {
  command -v clang++ >/dev/null || { echo "arref: fuzzing needs clang (apt-get install clang libclang-rt-14-dev)" >&2; exit 1; }
  CC=clang CXX=clang++ cmake -S . -B "$dir" -G Ninja -DCMAKE_BUILD_TYPE=Release -DARREF_FUZZ=ON \
    -DARREF_SANITIZE="$sanitize" -DARREF_WITH_PCL=OFF -DARREF_BUILD_TESTS=OFF >/dev/null
  cmake --build "$dir" -j "$(nproc)" --target "${1:-fuzzers}"
}

known() {
  local t
  for t in "${TARGETS[@]}"; do [[ $t == "$1" ]] && return 0; done
  echo "arref: unknown fuzz target '$1' (targets: ${TARGETS[*]})" >&2
  exit 2
}

# Sanitizer reports abort the run; known third-party leaks are listed in tests/sanitizers.
# Long runs keep no allocation stacks (malloc_context_size=0): ASan's stack records alone
# grew a server_config run past 600 MB (docs/fuzzing.md). Errors are still caught; replay
# the saved input with --replay to see the stacks.
user_asan=${ASAN_OPTIONS:-}
export ASAN_OPTIONS=${ASAN_OPTIONS:-halt_on_error=1:detect_leaks=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$(pwd)/tests/sanitizers/lsan.supp:print_suppressions=0}
# The mesh and URDF targets write small files: keep them in memory where possible.
[[ -d /dev/shm && -w /dev/shm ]] && export TMPDIR=${TMPDIR:-/dev/shm}

case ${1:-} in
  --build)
    build
    ;;
  --replay)
    target=${2:?"scripts/fuzz.sh --replay TARGET"}
    target=${target%_fuzz}
    known "$target"
    [[ $sanitize == address,undefined ]] || { echo "arref: --replay runs the ASan build: unset FUZZ_SANITIZE" >&2; exit 2; }
    build "${target}_fuzz"
    mkdir -p "$store/corpus/$target" "$store/crashes/$target"
    folders=("$store/corpus/$target" "tests/fuzz/corpus/$target")
    [[ -d tests/fuzz/regressions/$target ]] && folders+=("tests/fuzz/regressions/$target")
    echo "arref: fuzz replay: $target: $(find "${folders[@]}" -type f | wc -l) inputs under ASan + UBSan"
    "$dir/tests/fuzz/${target}_fuzz" -runs=0 -timeout=25 -rss_limit_mb=4096 -artifact_prefix="$store/crashes/$target/" \
      -print_final_stats=1 "${folders[@]}"
    ;;
  --smoke)
    seconds=${2:-20}
    build
    for t in "${TARGETS[@]}"; do
      work=$(mktemp -d)
      mkdir -p "$dir/crashes/$t"
      echo "arref: fuzz smoke: $t: seeds, reproducers, then ${seconds} s of mutations"
      # The working corpus is thrown away: the run starts from the repo's seeds every time.
      "$dir/tests/fuzz/${t}_fuzz" -max_total_time="$seconds" -seed=1 -max_len=65536 -timeout=25 -rss_limit_mb=4096 \
        -artifact_prefix="$dir/crashes/$t/" -print_final_stats=1 "$work" "tests/fuzz/corpus/$t" \
        $( [[ -d tests/fuzz/regressions/$t ]] && echo "tests/fuzz/regressions/$t" ) 2>"$dir/smoke-$t.log" ||
        { tail -60 "$dir/smoke-$t.log" >&2; rm -rf "$work"; echo "arref: fuzz smoke failed: $t (log $dir/smoke-$t.log)" >&2; exit 1; }
      grep -E "^stat::(number_of_executed_units|average_exec_per_sec)" "$dir/smoke-$t.log" | tr '\n' ' '
      grep -E "DONE|INITED" "$dir/smoke-$t.log" | tail -1
      rm -rf "$work"
    done
    ;;
  "" | -*)
    echo "usage: scripts/fuzz.sh TARGET SECONDS [libFuzzer options] | --smoke [SECONDS] | --build (targets: ${TARGETS[*]})" >&2
    exit 2
    ;;
  *)
    target=${1%_fuzz}
    known "$target"
    seconds=${2:?"scripts/fuzz.sh $target SECONDS"}
    shift 2
    build "${target}_fuzz"
    mkdir -p "$store/corpus/$target" "$store/crashes/$target"
    export ASAN_OPTIONS=${user_asan:-halt_on_error=1:detect_leaks=1:malloc_context_size=0}
    "$dir/tests/fuzz/${target}_fuzz" -max_total_time="$seconds" -max_len=65536 -timeout=25 -rss_limit_mb=4096 \
      -artifact_prefix="$store/crashes/$target/" -print_final_stats=1 "$@" \
      "$store/corpus/$target" "tests/fuzz/corpus/$target"
    ;;
esac
