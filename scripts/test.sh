#!/usr/bin/env bash
# The whole test suite on a fresh Debian 12 machine: install, build, run every test.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
# CI treats warnings as errors; a user's machine, with another compiler, only sees them.
if [[ ${CI:-} == true ]]; then bash scripts/build.sh -DARREF_WERROR=ON; else bash scripts/build.sh -DARREF_WERROR=OFF; fi
if [[ ! -d ../shared/robots ]]; then
  echo "arref: ../shared is absent: tests on the vendor KR5 package will be skipped (they need ../shared/robots)"
fi
ctest --test-dir build --output-on-failure -j "$(nproc)" "$@"
