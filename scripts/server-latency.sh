#!/usr/bin/env bash
# Server request latency bench (not a test): the real arref-server on loopback, one mock
# headset at a time, on simulated cells of every robot (the built-in one, and the vendor
# packages when ../shared/robots is there) made by both meshers, in the small (16,000 scene
# samples) and the big (256,000) configuration. Each cell's first request builds the robot's
# expected surfaces for that mesh resolution and is left out: the figures are of requests with
# the robot side cached. Prints a markdown table: latency (request sent -> result) and server
# time, median and p95, and the ADD against the simulator's truth.
# Usage: scripts/server-latency.sh [CELLS=3] [SEEDS=4] [REPEAT=3]   (build/ must be built)
set -euo pipefail
cd "$(dirname "$0")/.."
cells=${1:-3}
seeds=${2:-4}
repeat=${3:-3}
arref=build/clients/cli/arref
headset=build/clients/mock_headset/arref-mock-headset
out=$(mktemp -d /tmp/arref-latency.XXXXXX)
packages=../shared/robots
robots=("kr5 builtin")
if [[ -d $packages ]]; then
  packages=$(cd "$packages" && pwd)
  robots+=("abb_irb2400 $packages/abb_irb2400_support/urdf/irb2400.urdf"
           "kuka_kr5_arc $packages/kuka_kr5_support/urdf/kr5_arc.urdf"
           "motoman_mh5 $packages/motoman_mh5_support/urdf/mh5.urdf"
           "motoman_sia10d $packages/motoman_sia10d_support/urdf/sia10d.urdf")
else
  echo "server-latency: ../shared/robots is absent: the built-in robot only" >&2
fi
echo "server-latency: files in $out" >&2

start_server() {  # $1: scene samples; sets $server and $port
  local samples=$1 config="$out/server-$1.yaml"
  {
    echo "server: {address: 127.0.0.1, port: 0, workers: 2}"
    echo "registration: {scene_samples: $samples}"
    echo "robots:"
    for r in "${robots[@]}"; do
      set -- $r
      echo "  - {id: $1, urdf: $2, package_path: [$packages]}"
    done
  } >"$config"
  build/server/arref-server --config "$config" >"$out/stdout-$samples" 2>"$out/server-$samples.log" &
  server=$!
  port=""
  for _ in $(seq 300); do
    port=$(sed -n 's/^listening on 127\.0\.0\.1:\([0-9]*\)$/\1/p' "$out/stdout-$samples")
    [[ -n $port ]] && return 0
    sleep 0.1
  done
  echo "arref-server did not start:" >&2
  cat "$out/server-$samples.log" >&2
  exit 1
}
trap '[[ -n ${server:-} ]] && kill $server 2>/dev/null; wait 2>/dev/null || true' EXIT

for r in "${robots[@]}"; do
  set -- $r
  id=$1 urdf=$2
  robot_args=()
  [[ $urdf != builtin ]] && robot_args=(--robot "$urdf" --package-path "$packages")
  for mesher in own open3d; do
    for ((c = 1; c <= cells; c++)); do
      $arref simulate "${robot_args[@]}" --mesher $mesher --rng-seed $((c + 100)) --seeds "$seeds" \
        --mesh-out "$out/$id-$mesher-$c.ply" --truth-out "$out/$id-$mesher-$c.json" >/dev/null 2>&1
    done
  done
done

for preset in small big; do
  samples=16000
  [[ $preset == big ]] && samples=256000
  start_server $samples
  for r in "${robots[@]}"; do
    set -- $r
    id=$1
    truth_robot=()
    [[ $2 != builtin ]] && truth_robot=(--truth-robot "$2" --package-path "$packages")
    for mesher in own open3d; do
      for ((c = 1; c <= cells; c++)); do
        cell="$out/$id-$mesher-$c"
        for ((s = 0; s < seeds; s++)); do
          # One session per seed; a cell's first request (seed 0's first) is the warm-up.
          $headset --port "$port" --robot "$id" --scene "$cell.ply" --truth "$cell.json" "${truth_robot[@]}" --seed-index $s \
            --repeat "$repeat" --timeout 120 --json --log-level error >"$cell-$preset-$s.json" || true
          python3 - "$cell-$preset-$s.json" "$id" "$mesher" "$preset" "$s" >>"$out/requests.tsv" <<'PY'
import json, sys
path, robot, mesher, preset, seed = sys.argv[1:]
try:
    runs = json.load(open(path))["runs"]
except (ValueError, KeyError):
    print(f"{robot}\t{mesher}\t{preset}\tfailed\t\t\t")
    sys.exit()
for run in runs:
    for i, r in enumerate(run["registrations"]):
        if seed == "0" and i == 0:
            continue  # the warm-up: builds the expected surfaces for this cell's resolution
        add = r.get("truth_error", {}).get("add_m", float("nan"))
        print(f"{robot}\t{mesher}\t{preset}\t{r['status']}\t{r['latency_ms']:.1f}\t{r['server_ms']:.1f}\t{add * 1e3:.2f}")
PY
        done
      done
    done
  done
  kill $server 2>/dev/null || true
  wait $server 2>/dev/null || true
  server=""
done

python3 - "$out/requests.tsv" <<'PY'
import math, statistics as st, sys
rows = [l.rstrip("\n").split("\t") for l in open(sys.argv[1])]
def pct(v, q):
    v = sorted(v)
    return v[min(len(v) - 1, int(math.ceil(q * len(v))) - 1)] if v else float("nan")
groups = {}
for r in rows:
    groups.setdefault((r[2], r[0], r[1]), []).append(r)
print("| configuration | robot | mesher | requests | failed | latency median ms | latency p95 ms | server median ms | ADD median mm | within 10 mm |")
print("|---|---|---|---|---|---|---|---|---|---|")
order = {"small": 0, "big": 1}
for key in sorted(groups, key=lambda k: (order[k[0]], k[1], k[2])):
    g = groups[key]
    done = [r for r in g if r[3] in ("RESULT_STATUS_OK", "RESULT_STATUS_LOW_CONFIDENCE", "RESULT_STATUS_FAILED")]
    lat = [float(r[4]) for r in done]
    srv = [float(r[5]) for r in done]
    add = [float(r[6]) for r in done if r[6] != "nan"]
    within = sum(a <= 10 for a in add)
    if not done or not add:
        print(f"| {key[0]} | {key[1]} | {key[2]} | {len(g)} | {len(g) - len(done)} | | | | | |")
        continue
    print(f"| {key[0]} | {key[1]} | {key[2]} | {len(g)} | {len(g) - len(done)} | {st.median(lat):.0f} | {pct(lat, 0.95):.0f} | "
          f"{st.median(srv):.0f} | {st.median(add):.1f} | {within} / {len(add)} |")
for preset in ("small", "big"):
    lat = [float(r[4]) for r in rows if r[2] == preset and r[3].startswith("RESULT_STATUS")]
    if lat:
        print(f"\nall robots and meshers, {preset}: {len(lat)} requests, latency median {st.median(lat):.0f} ms, p95 {pct(lat, 0.95):.0f} ms")
PY
