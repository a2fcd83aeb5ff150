"""Record and replay: real sessions through the real server (mock headset and Python client), the
recordings replayed offline by `arref replay` and sent to a live server again, with the same results."""

import json
import subprocess

import numpy as np
import pytest

from arref_client import Client, errors, pb
from arref_client.recording import read_recording, send_recording
from arref_testing import ARREF, MOCK_HEADSET, ServerProcess

TOKEN = "cell-token-8d2f"
METHOD = "arref-icp-fast"
# Offline and live runs do the same arithmetic on the same inputs; the bound only allows for
# floating-point sums split differently across threads.
SAME_POSE_M = 1e-4


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, cell_ros):
    """Two sessions recorded by a server that requires a token: the C++ mock headset mapping a
    simulated cell, and the Python client uploading a mesh file with two requests and a refused one."""
    folder = tmp_path_factory.mktemp("recorded")
    record_dir = folder / "recordings"
    server = ServerProcess(folder, auth_token=TOKEN, record_dir=str(record_dir))
    try:
        mock = subprocess.run([MOCK_HEADSET, "--port", str(server.port), "--auth-token", TOKEN, "--rng-seed", "2",
                               "--method", METHOD, "--json"], capture_output=True, text=True, timeout=600)
        assert mock.returncode == 0, mock.stderr
        with Client("127.0.0.1", server.port, auth_token=TOKEN, client_name="python-recorded") as c:
            c.upload_mesh(cell_ros.mesh["ply"], frame="ros")
            c.set_seed(cell_ros.seed(0), frame="ros")
            live = [c.register("kr5", method=METHOD)]
            with pytest.raises(Exception):
                c.register("no-such-robot")
            live.append(c.register("kr5", seed=cell_ros.seed(1), frame="ros", method=METHOD))
            python_session = c.session_id
    finally:
        server.stop()
    files = sorted(record_dir.glob("*.arrec"))
    by_session = {read_recording(str(f)).header.session_id: str(f) for f in files}
    return {"mock": json.loads(mock.stdout), "python": live, "files": by_session, "python_session": python_session}


def replay_offline(path):
    out = subprocess.run([ARREF, "--log-level", "warn", "replay", path, "--json"], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    return [json.loads(line) for line in out.stdout.splitlines()]


def test_every_session_is_recorded_without_the_token(recorded):
    assert len(recorded["files"]) == 2
    for path in recorded["files"].values():
        with open(path, "rb") as f:
            data = f.read()
        assert TOKEN.encode() not in data
        rec = read_recording(path)
        assert rec.header.server_version and rec.header.protocol_version == pb.PROTOCOL_VERSION_CURRENT
        assert [r.id for r in rec.header.robots] == ["kr5"]
        assert "method: arref-icp" in rec.header.registration_yaml
        first = rec.messages[0].message
        assert first.WhichOneof("kind") == "hello" and first.hello.auth_token == ""
        times = [m.t_s for m in rec.messages]
        assert times == sorted(times) and times[0] >= 0


def test_python_session_recorded_message_by_message(recorded):
    rec = read_recording(recorded["files"][recorded["python_session"]])
    kinds = [m.message.WhichOneof("kind") for m in rec.messages]
    assert kinds[0] == "hello"
    assert kinds.count("register_request") == 3  # the refused one too
    assert "surface_upsert" in kinds and "seed_pose" in kinds


def test_offline_replay_gives_the_live_results(recorded):
    # the mock headset's session: results in Unity's frame
    answers = [a for a in replay_offline(recorded["files"][recorded["mock"]["session_id"]]) if "status" in a]
    live = recorded["mock"]["registrations"]
    assert len(answers) == len(live) == 1
    assert "RESULT_STATUS_" + answers[0]["status"] == live[0]["status"]
    np.testing.assert_allclose(answers[0]["position"] + answers[0]["orientation"], live[0]["T_world_base_unity"],
                               atol=SAME_POSE_M)

    # the Python session: two results and the refused request's error, in recorded order
    answers = replay_offline(recorded["files"][recorded["python_session"]])
    errors = [a for a in answers if "error" in a]
    results = [a for a in answers if "status" in a]
    assert [e["error"] for e in errors] == ["ERROR_CODE_UNKNOWN_ROBOT"]
    assert [r["request_id"] for r in results] == [r.request_id for r in recorded["python"]]
    for offline, live in zip(results, recorded["python"]):
        assert offline["status"] == live.status
        np.testing.assert_allclose(np.reshape(offline["T_world_base"], (4, 4)), live.matrix, atol=SAME_POSE_M)


def test_sent_again_fast_and_at_pace_gives_the_same_results(recorded, tmp_path):
    path = recorded["files"][recorded["python_session"]]
    original = read_recording(path)
    again_dir = tmp_path / "again"
    server = ServerProcess(tmp_path, record_dir=str(again_dir))  # no token now: the recording holds none
    try:
        fast = send_recording(path, "127.0.0.1", server.port, pace="fast")
        paced = send_recording(path, "127.0.0.1", server.port, pace="original")
        mock = subprocess.run([MOCK_HEADSET, "--port", str(server.port), "--send-recording", path, "--fast", "--json"],
                              capture_output=True, text=True, timeout=600)
    finally:
        server.stop()
    for out in (fast, paced):
        assert [e.code for e in out.errors] == [pb.ERROR_CODE_UNKNOWN_ROBOT]
        assert [r.request_id for r in out.results] == [r.request_id for r in recorded["python"]]
        for again, live in zip(out.results, recorded["python"]):
            assert again.status == live.status
            np.testing.assert_allclose(again.matrix, live.matrix, atol=SAME_POSE_M)
    assert mock.returncode == 0, mock.stderr
    j = json.loads(mock.stdout)
    # in the order they came back: sent back to back, the two requests run on both workers at once
    assert sorted(r["request_id"] for r in j["registrations"]) == [r.request_id for r in recorded["python"]]
    assert [e["code"] for e in j["errors"]] == ["ERROR_CODE_UNKNOWN_ROBOT"]

    # At the original pace the messages reached the server no sooner after one another than
    # they had in the cell (its own recording of the replayed session says when they arrived).
    replayed = read_recording(str(_recording_of(again_dir, paced.session_id)))
    def gaps(rec):
        t = [m.t_s for m in rec.messages if m.message.WhichOneof("kind") != "hello"]
        return np.array(t) - t[0]
    assert len(gaps(replayed)) == len(gaps(original))
    assert np.all(gaps(replayed) >= gaps(original) - 0.005)


def _recording_of(folder, session_id):
    for f in folder.glob("*.arrec"):
        if read_recording(str(f)).header.session_id == session_id:
            return f
    raise AssertionError(f"no recording of session {session_id} in {folder}")


def test_offline_replay_answers_cancel_subscribe_and_ping(tmp_path, cell_ros):
    """Cancel, Subscribe and Ping replayed offline: a request cancelled while it ran is CANCELLED,
    a Cancel of nothing in flight UNKNOWN_REQUEST, subscriptions and pings answered as live."""
    record_dir = tmp_path / "recordings"
    server = ServerProcess(tmp_path, record_dir=str(record_dir))
    try:
        with Client("127.0.0.1", server.port) as c:
            c.upload_mesh(cell_ros.mesh["ply"], frame="ros")  # ends with a Ping
            c.subscribe("kr5")
            m = pb.ClientMessage()
            m.subscribe.robot_id = "no-such-robot"
            c.send(m)
            with pytest.raises(errors.UnknownRobot):
                c.sync()
            cancelled = c.submit("kr5", seed=cell_ros.seed(0), frame="ros", method="arref-icp")
            c.cancel(cancelled)  # right after Accepted: the request is still queued or running
            live_cancelled = c.wait_result(cancelled, check=False)
            c.cancel(99)
            with pytest.raises(errors.UnknownRequest):
                c.sync()
            c.ping(payload=b"replayed")
            done = c.register("kr5", seed=cell_ros.seed(1), frame="ros", method=METHOD)
            c.cancel(done.request_id)  # answered already
            with pytest.raises(errors.UnknownRequest):
                c.sync()
            session_id = c.session_id
    finally:
        server.stop()
    assert live_cancelled.status == "CANCELLED"
    path = str(_recording_of(record_dir, session_id))
    nonces = [m.message.ping.nonce for m in read_recording(path).messages if m.message.WhichOneof("kind") == "ping"]
    answers = replay_offline(path)
    assert [a["pong"] for a in answers if "pong" in a] == nonces and len(nonces) >= 4
    assert [(a["subscribed"], a["subscribing"]) for a in answers if "subscribed" in a] == [("kr5", True)]
    assert [(a["error"], a["request_id"]) for a in answers if "error" in a] == [
        ("ERROR_CODE_UNKNOWN_ROBOT", 0), ("ERROR_CODE_UNKNOWN_REQUEST", 99),
        ("ERROR_CODE_UNKNOWN_REQUEST", done.request_id)]
    results = [a for a in answers if "status" in a]
    assert [(r["request_id"], r["status"]) for r in results] == [(cancelled, "CANCELLED"), (done.request_id, "OK")]
    assert "cancelled by the client" in results[0]["message"]
    np.testing.assert_allclose(np.reshape(results[1]["T_world_base"], (4, 4)), done.matrix, atol=SAME_POSE_M)
    # Answers in the order the session sent them: the cancelled request's before the Pong of
    # the Ping sent after its Cancel (the one after Cancel(99)).
    order = [("pong", a["pong"]) if "pong" in a else ("result", a["request_id"]) if "status" in a else None
             for a in answers]
    assert order.index(("pong", nonces[1])) < order.index(("result", cancelled)) < order.index(("pong", nonces[2]))
