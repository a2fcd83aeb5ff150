"""Tracking replayed offline by `arref replay`: a simulated stream scored against its truth, and a
tracking session recorded by the real server replayed like the live one."""

import json
import math
import subprocess

import numpy as np

from arref_client import Client, TrackTruth
from arref_client.recording import read_recording
from arref_client.tracking import matrix_from_pose, pose_error
from arref_testing import ARREF, SANITIZED, ServerProcess

SETTLED_S = 1.0   # the filter settling from the stream's seed, 4 cm and 3 deg off
WITHIN_M = 0.010
# Offline every frame is processed (none dropped, none late), so the live test's allowance for
# a loaded machine is not needed here.
WITHIN_FRACTION = 0.95


def replay(path, *args):
    out = subprocess.run([ARREF, "--log-level", "info", "replay", path, *args], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    return out


def updates_of(out):
    answers = [json.loads(line) for line in out.stdout.splitlines()]
    return [a for a in answers if "tracking_update" in a], [a for a in answers if "error" in a]


def ros_matrix(u):
    assert u["frame"] == "ros"
    return matrix_from_pose(u["position"] + u["orientation"])


def test_offline_replay_tracks_a_simulated_stream_frame_by_frame(track_stream):
    truth = TrackTruth.load(track_stream.truth_path)
    first = replay(track_stream.path, "--json")
    updates, errors = updates_of(first)
    assert not errors, errors
    assert [u["tracking_update"] for u in updates] == sorted(truth.frames)  # every frame, in order
    assert "tracking updates:" in first.stderr and "tracking" in first.stderr
    scored = [u for u in updates if truth.frames[u["tracking_update"]]["t_s"] >= SETTLED_S]
    assert len(scored) >= 50
    errors_m = []
    for u in scored:
        error_m, yaw_rad = pose_error(ros_matrix(u), truth.frames[u["tracking_update"]]["T_world_base"])
        errors_m.append(error_m if yaw_rad < math.radians(1.0) else math.inf)
        # the stream's clock is the recording's: frame times are the simulator's, in Unix time too
        assert abs(u["frame_time_s"] - truth.frames[u["tracking_update"]]["t_s"]) < 1e-6
        assert u["joint_staleness_s"] >= 0  # posed from the stream's joint states
    within = sum(e < WITHIN_M for e in errors_m)
    assert within >= WITHIN_FRACTION * len(scored), f"{within} of {len(scored)}: {sorted(errors_m)}"

    # The same recording gives the same updates (no frame dropped by timing).
    again, _ = updates_of(replay(track_stream.path, "--json"))
    assert [u["tracking_update"] for u in again] == [u["tracking_update"] for u in updates]
    for a, b in zip(again, updates):
        assert a["state"] == b["state"]
        np.testing.assert_allclose(a["position"], b["position"], atol=1e-6)

    human = replay(track_stream.path).stdout
    assert f"frame {max(truth.frames)} of kr5: " in human


def test_recorded_tracking_session_replays_like_the_live_one(tmp_path, track_stream):
    truth = TrackTruth.load(track_stream.truth_path)
    stream = read_recording(track_stream.path).messages
    record_dir = tmp_path / "recordings"
    server = ServerProcess(tmp_path, record_dir=str(record_dir))
    try:
        with Client("127.0.0.1", server.port) as c:
            live = c.track("kr5", stream)
            session_id = c.session_id
    finally:
        server.stop()
    assert not live.errors, [str(e) for e in live.errors]
    recordings = [str(f) for f in record_dir.glob("*.arrec") if read_recording(str(f)).header.session_id == session_id]
    assert len(recordings) == 1
    rec = read_recording(recordings[0])
    assert rec.header.HasField("start_server_time_s")
    kinds = {m.message.WhichOneof("kind") for m in rec.messages}
    assert {"track_request", "depth_frame", "joint_state", "clock_report"} <= kinds

    updates, errors = updates_of(replay(recordings[0], "--json"))
    assert not errors, errors
    assert len(updates) == live.frames_sent  # offline none is dropped
    offline = {u["tracking_update"]: u for u in updates}
    compared = 0
    for u in live.updates:
        o = offline[u.frame_id]
        # the frame's exposure, on the recording server's clocks
        assert abs(o["frame_time_s"] - u.frame_time_s) < 1e-6
        assert abs(o["frame_time_unix_s"] - u.frame_time_unix_s) < 0.005
        # A sanitized live server's filter, fed fewer frames, may drift apart from the replay's.
        if truth.frames[u.frame_id]["t_s"] < SETTLED_S or SANITIZED:
            continue
        compared += 1
        error_m, _ = pose_error(ros_matrix(o), truth.frames[u.frame_id]["T_world_base"])
        assert error_m < 0.02, f"frame {u.frame_id}: replayed {error_m * 1e3:.1f} mm off the truth"
        # the live server may have dropped frames, so its filter saw fewer: close, not equal
        assert np.linalg.norm(np.array(o["position"]) - u.matrix[:3, 3]) < 0.01
    assert compared >= 20 or SANITIZED
