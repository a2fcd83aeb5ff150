#!/usr/bin/python3
"""Scores `arref replay` of simulated tracking streams against their truth, one row per robot and
frame kind: `arref simulate-track` writes each stream (a jump half way), `arref replay --json`
re-runs it offline through the server's tracking service, and the updates are compared with the
simulator's T_world_base. Run from a built checkout with ../shared beside it:

    python3 scripts/replay-track-table.py [--seconds 6] [--rng-seed 11]

Frames within 10 mm count after the first second, leaving out the second after the jump."""

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [os.path.join(ROOT, "clients", "python"), os.path.join(ROOT, "build", "python")]
from arref_client.tracking import matrix_from_pose, pose_error  # noqa: E402

ARREF = os.path.join(ROOT, "build", "clients", "cli", "arref")
SHARED = os.path.join(os.path.dirname(ROOT), "shared", "robots")
ROBOTS = {"built-in": os.path.join(ROOT, "config", "robots", "kr5_primitive.urdf"),
          "KR5 arc": os.path.join(SHARED, "kuka_kr5_support", "urdf", "kr5_arc.urdf"),
          "IRB 2400": os.path.join(SHARED, "abb_irb2400_support", "urdf", "irb2400.urdf"),
          "MH5": os.path.join(SHARED, "motoman_mh5_support", "urdf", "mh5.urdf"),
          "SIA10D": os.path.join(SHARED, "motoman_sia10d_support", "urdf", "sia10d.urdf")}


def row(name, urdf, kind, args, folder):
    stream, truth_path = os.path.join(folder, "s.arrec"), os.path.join(folder, "t.json")
    config = os.path.join(folder, "c.yaml")
    with open(config, "w") as f:  # the replay serves the robot under simulate-track's id
        f.write(f"robots:\n  - id: kr5\n    urdf: {urdf}\n    package_path: {SHARED}\n")
    subprocess.run([ARREF, "--log-level", "warn", "simulate-track", "--robot", urdf, "--package-path", SHARED,
                    "--kind", kind, "--seconds", str(args.seconds), "--jump-at", str(args.seconds / 2),
                    "--rng-seed", str(args.rng_seed), "--stream-out", stream, "--truth-out", truth_path], check=True)
    truth = json.load(open(truth_path))
    frames = {f["frame_id"]: f for f in truth["frames"]}
    start = time.monotonic()
    out = subprocess.run([ARREF, "--log-level", "warn", "replay", stream, "--json", "--config", config],
                         capture_output=True, text=True, check=True)
    seconds = time.monotonic() - start
    updates = [json.loads(line) for line in out.stdout.splitlines() if "tracking_update" in line]
    errors = []
    for u in updates:
        f = frames[u["tracking_update"]]
        jump = truth["jump_time_s"]
        if f["t_s"] < 1.0 or jump <= f["t_s"] < jump + 1.0:
            continue
        e, yaw = pose_error(matrix_from_pose(u["position"] + u["orientation"]), np.array(f["T_world_base"]).reshape(4, 4))
        errors.append(e if yaw < math.radians(1) else math.inf)
    within = sum(e < 0.01 for e in errors)
    print(f"| {name} | {kind} | {len(frames)} | {len(updates)} | {100 * within / len(errors):.1f} % of {len(errors)} | "
          f"{1e3 * np.median(errors):.1f} | {seconds:.1f} |", flush=True)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=6.0)
    p.add_argument("--rng-seed", type=int, default=11)
    args = p.parse_args()
    if not os.path.isdir(SHARED):
        sys.exit(f"{SHARED} not found: the vendor robots are only beside CI's and developers' clones")
    print("| robot | kind | frames | updates | within 10 mm | median mm | replay s |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for name, urdf in ROBOTS.items():
            for kind in ("long-throw", "ahat"):
                row(name, urdf, kind, args, folder)


if __name__ == "__main__":
    main()
