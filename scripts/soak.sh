#!/usr/bin/env bash
# Soak / load bench (not a test): the real arref-server on loopback, CLIENTS mock headsets
# (every BAD_EVERY-th misbehaving: corrupt frame, oversized message, disconnect mid-upload,
# never reading) reconnecting and registering for SECONDS; prints throughput, latency per
# session, every error, and the server's RSS over time (growth after the warm-up).
# Usage: scripts/soak.sh [CLIENTS=50] [SECONDS=600] [BAD_EVERY=5]   (build/ must be built)
# ARREF_SERVER=PATH soaks another server binary (e.g. an older tree's, for a pair in the same hour).
# SOAK_NEW_SEEDS=1: each good headset's 2nd and 3rd request move the seed to the cell's next one
# (a new crop each time) instead of repeating the same request.
set -euo pipefail
cd "$(dirname "$0")/.."
clients=${1:-50}
seconds=${2:-600}
bad_every=${3:-5}
(( seconds <= 3600 )) || { echo "SECONDS is bounded to 3600" >&2; exit 2; }
out=$(mktemp -d /tmp/arref-soak.XXXXXX)
cat >"$out/server.yaml" <<YAML
server:
  address: 127.0.0.1
  port: 0
  workers: 2
  queue_size: $((clients * 2))
limits:
  max_connections_per_peer: $((clients * 2 + 16))
  max_send_queue_bytes: 1048576
robots:
  - id: kr5
    urdf: builtin
YAML
"${ARREF_SERVER:-build/server/arref-server}" --config "$out/server.yaml" >"$out/stdout" 2>"$out/server.log" &
server=$!
trap 'kill $server 2>/dev/null || true; wait $server 2>/dev/null || true' EXIT
port=""
for _ in $(seq 100); do
  port=$(sed -n 's/^listening on 127\.0\.0\.1:\([0-9]*\)$/\1/p' "$out/stdout")
  [[ -n $port ]] && break
  sleep 0.1
done
[[ -n $port ]] || { echo "arref-server did not start:" >&2; cat "$out/server.log" >&2; exit 1; }
# RSS every 5 s while the soak runs.
(
  start=$(date +%s)
  while kill -0 $server 2>/dev/null; do
    echo "$(( $(date +%s) - start )) $(awk '/^VmRSS:/ {print $2}' /proc/$server/status)"
    sleep 5
  done
) >"$out/rss" &
sampler=$!
echo "soak: $clients headsets for $seconds s against 127.0.0.1:$port (every $bad_every-th misbehaves); files in $out"
status=0
# The server's CPU time (user + system, in clock ticks) before and after: CPU per result bounds
# the throughput any number of clients can get from this machine's cores.
cpu_ticks() { awk '{print $14 + $15}' /proc/$server/stat; }
cpu_start=$(cpu_ticks)
build/clients/mock_headset/arref-mock-headset --port "$port" --clients "$clients" --soak "$seconds" \
  --bad-every "$bad_every" --batch-interval 0.01 --timeout 300 --log-level error \
  ${SOAK_NEW_SEEDS:+--new-seed-each-repeat} | tee "$out/mock" || status=$?
cpu_end=$(cpu_ticks)
kill $sampler 2>/dev/null || true
results=$(sed -n 's/^soak: .* \([0-9]*\) results, .*/\1/p' "$out/mock")
awk -v t=$((cpu_end - cpu_start)) -v hz="$(getconf CLK_TCK)" -v n="${results:-0}" -v cores="$(nproc)" 'BEGIN {
  s = t / hz
  if (n > 0) printf "server CPU: %.0f s for %d results: %.0f ms per result, so at most %.1f results/s on %d cores\n",
    s, n, 1000 * s / n, cores * n / s, cores
}'
# RSS after the warm-up (a tenth of the run, at least the first sample) against the end and the peak.
awk -v warm=$(( seconds / 10 )) '
  { t[NR] = $1; r[NR] = $2; if ($2 > peak) peak = $2 }
  END {
    for (i = 1; i <= NR; i++) if (t[i] >= warm) { w = i; break }
    if (!w) w = 1
    printf "server RSS: %.1f MiB at %d s (after warm-up), %.1f MiB at %d s (end), peak %.1f MiB; growth after warm-up %.1f %%\n",
      r[w] / 1024, t[w], r[NR] / 1024, t[NR], peak / 1024, 100 * (r[NR] - r[w]) / r[w]
  }' "$out/rss"
echo "server log: $(grep -c '\[warning\]' "$out/server.log") warnings, $(grep -c '\[error\]' "$out/server.log") errors"
grep '\[error\]' "$out/server.log" | head -5 || true
kill -0 $server 2>/dev/null && echo "server alive at the end" || { echo "server died" >&2; status=1; }
exit $status
