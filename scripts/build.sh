#!/usr/bin/env bash
# Configures and builds arref in ./build (Release, Ninja). Extra arguments go to CMake.
# ARREF_BUILD_DIR picks another folder (scripts/test.sh uses it for sanitizer builds).
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=$(nproc)
dir=${ARREF_BUILD_DIR:-build}
cmake -S . -B "$dir" -G Ninja -DCMAKE_BUILD_TYPE=Release "$@" >/dev/null
cmake --build "$dir" -j "$jobs"
