"""Continuous referencing through the Python client against the real arref-server, on a stream of
the C++ track simulator (`arref simulate-track`) with the true T_world_base of every frame."""

import json
import math
import time

import numpy as np
import pytest

from arref_client import Client, ClockOffsetEstimator, TrackTruth, errors, pb
from arref_client.recording import read_recording
from arref_client.tracking import matrix_from_pose, pose_error
from arref_testing import SANITIZED, TrackStream, python_cli

# The tracker holds the base within 10 mm on >= 95 % of simulated long-throw frames
# by ADD (docs/tracking.md); here the base origin is scored, whose error on this stream is about
# 5 mm (median), and a loaded test machine drops and delays frames, hence 90 % and 8 mm.
WITHIN_M = 0.010
WITHIN_FRACTION = 0.9
SETTLED_S = 1.0  # the first second is the filter settling from a seed 4 cm and 3 deg off
# Updates after that second to check, of 60 frames: a loaded machine drops some, and a sanitized
# server (TSan on one CPU: scripts/test.sh) most of them; its updates are still checked one by one.
MIN_SCORED = 5 if SANITIZED else 20


def test_clock_offset_estimator_takes_the_shortest_round_trip():
    e = ClockOffsetEstimator()
    # server = sender + 5 s; a slow exchange whose delays are lopsided, then a fast symmetric one
    e.add(10.0, 15.030, 15.031, 10.040)
    e.add(11.0, 16.001, 16.002, 11.003)
    assert e.offset_s == pytest.approx(5.0, abs=1e-9)
    assert e.uncertainty_s == pytest.approx(0.001, abs=1e-9)
    with pytest.raises(ValueError):
        e.add(12.0, 17.0, 16.0, 12.1)  # the server answered before it received


def test_matrix_from_pose_matches_a_yaw():
    yaw = 0.7
    T = matrix_from_pose((1, 2, 3, 0, 0, math.sin(yaw / 2), math.cos(yaw / 2)))
    np.testing.assert_allclose(T[:3, :3], [[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0],
                                           [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3])


def test_track_follows_the_simulated_robot(server, track_stream):
    stream = read_recording(track_stream.path).messages
    truth = TrackTruth.load(track_stream.truth_path)
    with Client("127.0.0.1", server.port) as c:
        out = c.track("kr5", stream)
    assert not out.errors, [str(e) for e in out.errors]
    assert out.frames_sent == len(truth.frames)
    assert len(out.updates) + out.frames_dropped == out.frames_sent
    ids = [u.frame_id for u in out.updates]
    assert ids == sorted(ids) and len(set(ids)) == len(ids)
    # The server and this client share the machine's clocks: the offset is its steady clock's
    # minus Unix time, found to well within a millisecond over loopback.
    assert out.clock_uncertainty_s < 0.005

    scored = [u for u in out.updates if truth.frames[u.frame_id]["t_s"] >= SETTLED_S]
    assert len(scored) > MIN_SCORED
    errors_m = []
    for u in scored:
        assert u.frame == "ros" and u.robot_id == "kr5" and u.session_id == c.session_id
        error_m, yaw_rad = pose_error(u.matrix, truth.frames[u.frame_id]["T_world_base"])
        errors_m.append(error_m if yaw_rad < math.radians(1.0) else math.inf)
        # The frame's data time in Unix time: the time this client stamped it with (its clock is
        # time.time), through the clock report, to within the clock estimate.
        assert abs(u.frame_time_unix_s - out.sent_times[u.frame_id]) < 0.005
        # Posed with the joints of the frame's instant, from the joint stream.
        true_joints = truth.frames[u.frame_id]["joints"]
        assert set(u.joints) == set(true_joints)
        assert max(abs(u.joints[k] - v) for k, v in true_joints.items()) < 0.01
        assert np.all(np.isfinite(u.covariance)) and np.all(np.diag(u.covariance) > 0)
    # The long-throw camera's 1 % of range, as the server measures it from the frames.
    assert abs(scored[-1].depth_noise - 0.0105) < 0.001
    within = sum(e < WITHIN_M for e in errors_m)
    if SANITIZED:
        return
    assert within >= WITHIN_FRACTION * len(scored), f"{within} of {len(scored)} within 10 mm: {sorted(errors_m)}"
    assert np.median(errors_m) < 0.008
    assert sum(u.good for u in scored) >= WITHIN_FRACTION * len(scored)


def _median_error_m(out, truth):
    scored = [u for u in out.updates if truth.frames[u.frame_id]["t_s"] >= SETTLED_S]
    assert len(scored) > MIN_SCORED
    return float(np.median([pose_error(u.matrix, truth.frames[u.frame_id]["T_world_base"])[0] for u in scored]))


def test_track_takes_the_streams_declared_camera_pose_latency(server, tmp_path):
    """A stream whose camera poses are 150 ms late, with a TrackRequest that says so: track() passes
    the latency on and the server takes each pose back to its exposure; told 0 instead, the same
    stream's base is further off (6.7 against 14.9 mm median, base origin; at 60 ms this short walk
    gave 5.4 against 6.5 mm, too close to hold on a loaded machine)."""
    late = TrackStream(tmp_path, 7, declared_latency_ms=150)
    stream = read_recording(late.path).messages
    truth = TrackTruth.load(late.truth_path)
    with Client("127.0.0.1", server.port) as c:
        said = c.track("kr5", stream)
        not_said = c.track("kr5", stream, camera_pose_latency_s=0.0)
    assert not said.errors and not not_said.errors
    if SANITIZED:
        return
    assert _median_error_m(said, truth) < 0.008
    assert _median_error_m(said, truth) < 0.75 * _median_error_m(not_said, truth)


def test_tracking_errors_are_typed_and_keep_the_session(server):
    with Client("127.0.0.1", server.port) as c:
        depth = np.full((2, 4), 1000, dtype=np.uint16)
        c.send_depth_frame("kr5", 1, depth, (10, 10, 2, 1), (0, 0, 1, 0, 0, 0, 1), timestamp_s=time.time())
        with pytest.raises(errors.NotTracking) as e:
            c.sync()
        assert e.value.code == pb.ERROR_CODE_NOT_TRACKING and "TrackRequest" in e.value.message

        m = pb.ClientMessage()
        m.depth_frame.robot_id, m.depth_frame.width, m.depth_frame.height = "kr5", 4, 2
        m.depth_frame.fx = m.depth_frame.fy = 10
        m.depth_frame.depth_mm = b"\x01" * 15  # one byte short of 4 x 2 uint16
        m.depth_frame.frame = pb.FRAME_CONVENTION_ROS
        m.depth_frame.T_world_camera.orientation.w = 1
        c.send(m)
        with pytest.raises(errors.BadDepthFrame) as e:
            c.sync()
        assert e.value.code == pb.ERROR_CODE_BAD_DEPTH_FRAME and "15 bytes" in e.value.message

        with pytest.raises(errors.UnknownRobot) as e:
            c.start_tracking("no-such-robot", (1, 0, 0, 0, 0, 0, 1))
        assert e.value.code == pb.ERROR_CODE_UNKNOWN_ROBOT
        with pytest.raises(errors.NoSeed):
            c.start_tracking("kr5")
        with pytest.raises(errors.InvalidArgument) as e:
            c.start_tracking("kr5", (1, 0, 0, 0, 0, 0, 1), camera_pose_latency_s=-0.5)
        assert "camera pose latency -0.5 s" in e.value.message
        assert c.ping() > 0  # the session goes on


def test_cli_track_prints_each_update_with_its_error(server, track_stream):
    p = python_cli("--port", str(server.port), "track", "--stream", track_stream.path, "--truth",
                   track_stream.truth_path, timeout=300)
    assert p.returncode == 0, p.stderr
    updates = [json.loads(line) for line in p.stdout.splitlines()]
    truth = TrackTruth.load(track_stream.truth_path)
    settled = [u for u in updates if truth.frames[u["frame_id"]]["t_s"] >= SETTLED_S]
    assert len(settled) > MIN_SCORED
    assert "frames sent" in p.stderr and "base error vs truth median" in p.stderr
    if not SANITIZED:  # a sanitized server's updates are checked, not their accuracy
        assert np.median([u["error_mm"] for u in settled]) < 8.0
