#!/usr/bin/env bash
# The main job on a fresh Debian 12 machine: install, build, then the demo: arref-server with
# its default config on loopback, and the mock headset mapping a simulated KR5 cell, placing a
# seed, requesting registration and printing the transform, RMS and the true error.
# Arguments go to the mock headset (e.g. --rng-seed 3 --seed-index 2 --method pcl-icp).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh

out=$(mktemp -d)
trap 'kill -TERM "$server" 2>/dev/null || true; wait "$server" 2>/dev/null || true; rm -rf "$out"' EXIT
build/server/arref-server --address 127.0.0.1 --port 0 >"$out/stdout" 2>"$out/server.log" &
server=$!
for _ in $(seq 100); do
  grep -q '^listening on' "$out/stdout" && break
  kill -0 "$server" 2>/dev/null || { cat "$out/server.log" >&2; exit 1; }
  sleep 0.1
done
port=$(sed -n 's/^listening on .*:\([0-9]*\)$/\1/p' "$out/stdout")
[[ -n $port ]] || { echo "arref-server did not start:" >&2; cat "$out/server.log" >&2; exit 1; }
echo "arref-server listening on 127.0.0.1:$port (log: server.log); the mock headset maps a simulated cell:"
build/clients/mock_headset/arref-mock-headset --port "$port" --log-level info "$@"
