#!/usr/bin/env bash
# The main job on a fresh Debian 12 machine: install, build, run the demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
exec build/clients/cli/arref demo "$@"
