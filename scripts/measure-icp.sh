#!/usr/bin/env bash
# Measures `arref register` (default method) from user-like seeds on simulated small-preset
# cells and prints success rates, median errors and median stage times.
# Usage: [METHOD=name] [SIM_ARGS="--table-gap 0.05 ..."] [REGISTER_ARGS="--samples 256000"] scripts/measure-icp.sh [CELLS] [SEEDS_PER_CELL] [robot args...]
# e.g.   scripts/measure-icp.sh 10 10 --robot ../shared/robots/kuka_kr5_support/urdf/kr5_arc.urdf --package-path ../shared/robots
set -euo pipefail
cd "$(dirname "$0")/.."
cells=${1:-10}; seeds=${2:-10}; shift 2 || true
arref=build/clients/cli/arref
out=$(mktemp -d)
for ((c = 1; c <= cells; c++)); do
  $arref simulate "$@" ${SIM_ARGS:-} --rng-seed "$c" --seeds "$seeds" --mesh-out "$out/c$c.ply" --truth-out "$out/c$c.json" 2>/dev/null
  for ((s = 0; s < seeds; s++)); do
    $arref register "$@" ${REGISTER_ARGS:-} --method "${METHOD:-arref-icp}" --scene "$out/c$c.ply" --truth "$out/c$c.json" --seed-index "$s" --json >> "$out/results.jsonl" || true
  done
done
python3 - "$out/results.jsonl" <<'PY'
import json, statistics as st, sys
rows = []  # the file holds pretty-printed JSON objects one after another
text = open(sys.argv[1]).read()
dec = json.JSONDecoder(); i = 0
while i < len(text):
    while i < len(text) and text[i].isspace(): i += 1
    if i >= len(text): break
    obj, i = dec.raw_decode(text, i); rows.append(obj)
add = [r["add_m"] * 1e3 for r in rows]
n = len(rows)
print(f"runs {n}")
print(f"success ADD<=10mm {sum(a <= 10 for a in add) / n * 100:.1f} %, ADD<=20mm {sum(a <= 20 for a in add) / n * 100:.1f} %")
print(f"median ADD {st.median(add):.1f} mm, p95 {sorted(add)[int(0.95 * (n - 1))]:.1f} mm, max {max(add):.1f} mm")
print(f"median translation {st.median(r['translation_error_m'] * 1e3 for r in rows):.1f} mm, "
      f"median rotation {st.median(r['rotation_error_deg'] for r in rows):.2f} deg, median rms {st.median(r['rms_m'] * 1e3 for r in rows):.1f} mm")
stages = rows[0]["timings_ms"].keys()
from collections import Counter
print("status: " + ", ".join(f"{k} {v}" for k, v in sorted(Counter(r["status"] for r in rows).items())))
wrong_ok = sum(r["status"] == "OK" and r["add_m"] > 0.02 for r in rows)
print(f"wrong poses (ADD > 20 mm) marked OK: {wrong_ok}")
good = [r for r in rows if r["add_m"] <= 0.02]
bad = [r for r in rows if r["add_m"] > 0.02]
for name, group in (("ADD <= 20 mm", good), ("ADD > 20 mm", bad)):
    if group:
        print(f"{name}: inlier fraction min {min(r['inlier_fraction'] for r in group):.3f} max {max(r['inlier_fraction'] for r in group):.3f}, "
              f"margin min {min(r.get('margin', -1) for r in group):.3f} max {max(r.get('margin', -1) for r in group):.3f}")
print("median stage times (ms): " + ", ".join(f"{s} {st.median(r['timings_ms'][s] for r in rows):.1f}" for s in stages))
PY
rm -rf "$out"
