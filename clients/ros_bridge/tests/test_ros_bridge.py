"""arref-ros-bridge against a real roscore (started and stopped here) and the real arref-server: a
registration appears on tf with the configured frames, the result's data stamp and its values;
a LOW_CONFIDENCE one does not; the bridge reconnects by itself when the server comes back; a
tracking session's updates appear on /tf with the frames' exposure times as stamps, near the
simulator's truth."""

import os
import signal
import socket
import subprocess
import sys
import time
import xmlrpc.client

import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "python", "tests"))
from arref_testing import Cell, ServerProcess, TrackStream  # noqa: E402

from arref_client import Client, TrackTruth  # noqa: E402
from arref_client.recording import read_recording  # noqa: E402
from arref_client.tracking import pose_error  # noqa: E402
from arref_client.ros_bridge import quaternion_from_matrix  # noqa: E402

BRIDGE = os.path.join(os.path.dirname(__file__), "..", "arref-ros-bridge")
PARENT, CHILD = "hololens_world", "kr5_base"
WAIT_S = 120.0  # only so that a broken bridge fails instead of hanging


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(predicate, what, timeout=WAIT_S):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what() if callable(what) else what}")


def start_bridge(ros, args, log_path):
    """The bridge, once it has subscribed to the server and this node's /tf subscription has
    connected to its publisher. /tf is not latched: what the bridge publishes before that
    connection is made (asynchronously, through the master) never reaches this node, and on a
    loaded machine that can be the first seconds of a stream."""
    connected = ros["tf_subscriber"].get_num_connections
    wait_for(lambda: connected() == 0, "the previous bridge's /tf connection to close")
    bridge = Process([sys.executable, BRIDGE, *args], str(log_path), ros["env"])
    wait_for(lambda: "publishing robot 'kr5'" in bridge.log(), f"the bridge to subscribe\n{bridge.log()}")
    wait_for(lambda: connected() >= 1, f"this node's /tf subscription to connect to the bridge\n{bridge.log()}")
    return bridge


class Process:
    """A child process in its own process group (roscore starts rosmaster and rosout), logging to a file."""

    def __init__(self, args, log_path, env):
        self.log_path = log_path
        self._log = open(log_path, "w")
        self.proc = subprocess.Popen(args, stdout=self._log, stderr=subprocess.STDOUT, env=env, start_new_session=True)

    def log(self):
        self._log.flush()
        with open(self.log_path) as f:
            return f.read()

    def stop(self, sig=signal.SIGINT):
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, sig)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        self._log.close()


@pytest.fixture(scope="module")
def ros(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ros")
    port = free_port()
    uri = f"http://127.0.0.1:{port}"
    env = dict(os.environ, ROS_MASTER_URI=uri, ROS_HOME=str(folder), ROS_IP="127.0.0.1", ROS_HOSTNAME="127.0.0.1")
    core = Process(["roscore", "-p", str(port)], str(folder / "roscore.log"), env)

    def master_up():
        try:
            return xmlrpc.client.ServerProxy(uri).getPid("/arref_test")[0] == 1
        except OSError:
            return False

    try:
        wait_for(master_up, f"roscore on {uri}\n{core.log()}")
        os.environ.update({k: env[k] for k in ("ROS_MASTER_URI", "ROS_HOME", "ROS_IP", "ROS_HOSTNAME")})
        import rospy
        import tf2_ros
        from tf2_msgs.msg import TFMessage

        rospy.init_node("arref_bridge_test", anonymous=True, disable_signals=True)
        buffer = tf2_ros.Buffer()
        listener = tf2_ros.TransformListener(buffer)
        static_messages = []
        rospy.Subscriber("/tf_static", TFMessage, static_messages.append)
        dynamic = []  # (TFMessage, Unix time received)
        tf_subscriber = rospy.Subscriber("/tf", TFMessage, lambda m: dynamic.append((m, time.time())))
        yield {"env": env, "buffer": buffer, "listener": listener, "static": static_messages, "dynamic": dynamic,
               "tf_subscriber": tf_subscriber, "folder": folder}
        rospy.signal_shutdown("test done")
    finally:
        core.stop()


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    return Cell(tmp_path_factory.mktemp("cell"), "ros", 6)


def lookup(buffer):
    import rospy

    if not buffer.can_transform(PARENT, CHILD, rospy.Time(0)):
        return None
    return buffer.lookup_transform(PARENT, CHILD, rospy.Time(0))


def latest_static(ros):
    """The robot's transform as last sent on /tf_static (tf2 answers a static lookup with the
    time asked for, so the stamp is read from the message itself)."""
    for msg in reversed(ros["static"]):
        for t in msg.transforms:
            if t.child_frame_id == CHILD:
                return t
    return None


def assert_is_result(t, sent, result):
    """t: what tf2 answers for PARENT -> CHILD; sent: the /tf_static message's transform."""
    for x in (t, sent):
        assert x.header.frame_id == PARENT and x.child_frame_id == CHILD
        tr, q = x.transform.translation, x.transform.rotation
        np.testing.assert_allclose([tr.x, tr.y, tr.z], result.matrix[:3, 3], atol=1e-9)
        expected = np.array(quaternion_from_matrix(result.matrix[:3, :3]))
        got = np.array([q.x, q.y, q.z, q.w])
        assert min(np.abs(got - expected).max(), np.abs(got + expected).max()) < 1e-9
    # the time its data was taken (the request's scene), not when it was published
    assert result.proto.scene_time_unix_s > 0
    assert abs(sent.header.stamp.to_sec() - result.proto.scene_time_unix_s) < 1e-6


def test_registration_appears_on_tf_and_survives_a_server_restart(ros, cell, tmp_path):
    port = free_port()
    server = ServerProcess(tmp_path, port=port)
    bridge = start_bridge(ros, ["--port", str(port), "--robot", f"kr5:{CHILD}:{PARENT}", "--reconnect", "0.5"],
                          tmp_path / "bridge.log")
    try:
        with Client("127.0.0.1", port) as c:
            c.upload_mesh(cell.mesh["ply"])
            first = c.register("kr5", seed=cell.seed(0), method="arref-icp-fast")
            received_at = time.time()
        assert first.status == "OK", first.message
        t = wait_for(lambda: lookup(ros["buffer"]), f"{PARENT} -> {CHILD} on tf\n{bridge.log()}")
        sent = wait_for(lambda: latest_static(ros), "the transform on /tf_static")
        assert_is_result(t, sent, first)
        assert sent.header.stamp.to_sec() < received_at
        np.testing.assert_allclose(first.matrix[:3, 3], cell.T_world_base[:3, 3], atol=0.03)

        # LOW_CONFIDENCE (pcl-icp never says OK) is not published: tf keeps the OK result.
        with Client("127.0.0.1", port) as c:
            c.upload_mesh(cell.mesh["ply"])
            doubtful = c.register("kr5", seed=cell.seed(1), method="pcl-icp")
        assert doubtful.status == "LOW_CONFIDENCE"
        wait_for(lambda: f"request {doubtful.request_id}: LOW_CONFIDENCE" in bridge.log(), "the bridge to skip it")
        assert_is_result(lookup(ros["buffer"]), latest_static(ros), first)

        # The server goes away and comes back on the same port: the bridge reconnects by itself.
        server.stop()
        wait_for(lambda: "connection to arref-server lost" in bridge.log(), f"the bridge to notice\n{bridge.log()}")
        server = ServerProcess(tmp_path, port=port)
        wait_for(lambda: "reconnected to arref-server" in bridge.log(), f"the bridge to reconnect\n{bridge.log()}")
        with Client("127.0.0.1", port) as c:
            c.upload_mesh(cell.mesh["ply"])
            second = c.register("kr5", seed=cell.seed(2), method="arref-icp-fast")
        assert second.status == "OK"
        wait_for(lambda: (lambda t: t and abs(t.header.stamp.to_sec() - second.proto.scene_time_unix_s) < 1e-6)(
            latest_static(ros)), f"the second result on /tf_static\n{bridge.log()}")
        wait_for(lambda: (lambda t: t and abs(t.transform.translation.x - second.matrix[0, 3]) < 1e-9)(
            lookup(ros["buffer"])), "tf2 to take the second result")
        assert_is_result(lookup(ros["buffer"]), latest_static(ros), second)
    finally:
        bridge.stop(signal.SIGTERM)
        server.stop()
    assert bridge.proc.returncode == 0, bridge.log()


TRACK_CHILD = "kr5_tracked_base"  # not CHILD: tf2 keeps a frame static once it was sent as static


def test_tracking_updates_appear_on_tf_with_their_frame_times(ros, tmp_path):
    import rospy

    stream = TrackStream(tmp_path, 7)
    truth = TrackTruth.load(stream.truth_path)
    server = ServerProcess(tmp_path)
    bridge = start_bridge(ros, ["--port", str(server.port), "--robot", f"kr5:{TRACK_CHILD}:{PARENT}"],
                          tmp_path / "bridge.log")
    try:
        with Client("127.0.0.1", server.port) as c:
            out = c.track("kr5", read_recording(stream.path).messages)
        assert not out.errors, [str(e) for e in out.errors]
        good = {u.frame_id: u for u in out.updates if u.good}
        assert len(good) > 20, f"{len(good)} of {len(out.updates)} updates in a good state"

        def ours():
            return [(t, at) for m, at in ros["dynamic"] for t in m.transforms if t.child_frame_id == TRACK_CHILD]

        wait_for(lambda: len(ours()) >= len(good),
                 lambda: f"{len(good)} transforms on /tf ({len(ours())} came)\n{bridge.log()}")
        time.sleep(0.5)  # anything more would be published by now
        published = ours()
        # Exactly the updates in a good state, once each, in order, with their values; stamped
        # with the frame's exposure (the time the client stamped it with), not when published.
        frame_times = np.array([u.frame_time_unix_s for u in good.values()])
        good_updates = list(good.values())
        assert len(published) == len(good)
        stamps = [t.header.stamp.to_sec() for t, _ in published]
        assert stamps == sorted(stamps)
        within, scored, matched = 0, 0, set()
        for t, received_at in published:
            assert t.header.frame_id == PARENT
            # ROS time holds nanoseconds; frames are 33 ms apart
            stamp = t.header.stamp.to_sec()
            nearest = int(np.argmin(np.abs(frame_times - stamp)))
            assert abs(frame_times[nearest] - stamp) < 1e-5, f"stamp {stamp:.6f} is no good update's frame time"
            u = good_updates[nearest]
            matched.add(u.frame_id)
            assert abs(t.header.stamp.to_sec() - out.sent_times[u.frame_id]) < 0.005
            assert received_at > t.header.stamp.to_sec()
            tr, q = t.transform.translation, t.transform.rotation
            np.testing.assert_allclose([tr.x, tr.y, tr.z], u.pose[:3], atol=1e-9)
            np.testing.assert_allclose([q.x, q.y, q.z, q.w], np.asarray(u.pose[3:]) / np.linalg.norm(u.pose[3:]),
                                       atol=1e-9)
            frame_truth = truth.frames[u.frame_id]
            if frame_truth["t_s"] >= 1.0:
                scored += 1
                error_m, yaw_rad = pose_error(u.matrix, frame_truth["T_world_base"])
                within += error_m < 0.01 and yaw_rad < np.radians(1.0)
        assert matched == set(good)
        assert scored > 20 and within >= 0.9 * scored, f"{within} of {scored} within 10 mm of the truth"
        # tf2 answers a lookup at a frame's time with that frame's update.
        t, _ = published[len(published) // 2]
        looked_up = ros["buffer"].lookup_transform(PARENT, TRACK_CHILD, t.header.stamp, rospy.Duration(5.0))
        assert looked_up.transform.translation.x == pytest.approx(t.transform.translation.x, abs=1e-9)
        assert "tracking (session" in bridge.log()
    finally:
        bridge.stop(signal.SIGTERM)
        server.stop()
    assert bridge.proc.returncode == 0, bridge.log()


SWITCH_CHILD = "kr5_registered_then_tracked"


def static_frames(ros):
    """Child frames of the last /tf_static message (a latched topic keeps only its last one)."""
    return {t.child_frame_id for t in ros["static"][-1].transforms} if ros["static"] else set()


def test_a_registered_robot_that_is_then_tracked_moves_to_tf(ros, cell, tmp_path):
    """A robot first registered (on /tf_static) and then tracked is withdrawn from /tf_static and
    published on /tf from then on. A listener started after that answers a lookup at a frame's
    stamp with that frame's update; one that had the frame as static answers every stamp with
    the newest transform, which is why the bridge never keeps a tracked robot static."""
    import rospy
    import tf2_ros

    stream = TrackStream(tmp_path, 8, seconds=2.0)
    messages = read_recording(stream.path).messages
    server = ServerProcess(tmp_path)
    bridge = start_bridge(ros, ["--port", str(server.port), "--robot", f"kr5:{SWITCH_CHILD}:{PARENT}"],
                          tmp_path / "bridge.log")
    try:
        with Client("127.0.0.1", server.port) as c:
            c.upload_mesh(cell.mesh["ply"])
            registered = c.register("kr5", seed=cell.seed(0), method="arref-icp-fast")
        assert registered.status == "OK", registered.message
        wait_for(lambda: SWITCH_CHILD in static_frames(ros), f"the registration on /tf_static\n{bridge.log()}")
        stale_buffer = ros["buffer"]  # has the frame as static now
        wait_for(lambda: stale_buffer.can_transform(PARENT, SWITCH_CHILD, rospy.Time(0)), "the static frame in tf2")

        with Client("127.0.0.1", server.port) as c:
            first = c.track("kr5", messages)
        assert any(u.good for u in first.updates)
        wait_for(lambda: "is tracked but was not configured as tracked" in bridge.log(), f"the switch\n{bridge.log()}")
        wait_for(lambda: SWITCH_CHILD not in static_frames(ros), f"the withdrawal from /tf_static\n{bridge.log()}")

        fresh = tf2_ros.Buffer()
        listener = tf2_ros.TransformListener(fresh)  # noqa: F841 (keeps the subscription)
        time.sleep(1.0)  # its subscriptions connect (and get the latched /tf_static, now without the robot)
        with Client("127.0.0.1", server.port) as c:
            second = c.track("kr5", messages)
        good = [u for u in second.updates if u.good]
        assert len(good) > 10
        wait_for(lambda: fresh.can_transform(PARENT, SWITCH_CHILD, rospy.Time.from_sec(good[-1].frame_time_unix_s)),
                 f"the last tracking update in the fresh listener\n{bridge.log()}")
        early = good[len(good) // 4]
        answered = fresh.lookup_transform(PARENT, SWITCH_CHILD, rospy.Time.from_sec(early.frame_time_unix_s))
        assert answered.transform.translation.x == pytest.approx(early.pose[0], abs=1e-9)
        assert answered.transform.translation.y == pytest.approx(early.pose[1], abs=1e-9)
        # tf2's static cache in the listener that saw the frame static: the newest, at any stamp
        # (the newest update on /tf, which the earlier frame's is not).
        newest = stale_buffer.lookup_transform(PARENT, SWITCH_CHILD, rospy.Time.from_sec(early.frame_time_unix_s))
        if abs(good[-1].pose[0] - early.pose[0]) > 1e-6:
            assert newest.transform.translation.x != pytest.approx(early.pose[0], abs=1e-9)

        # A registration of the robot now goes to /tf, stamped with its data's time.
        with Client("127.0.0.1", server.port) as c:
            c.upload_mesh(cell.mesh["ply"])
            again = c.register("kr5", seed=cell.seed(1), method="arref-icp-fast")
        assert again.status == "OK"
        stamp = again.proto.scene_time_unix_s

        def on_tf():
            return [t for m, _ in ros["dynamic"] for t in m.transforms
                    if t.child_frame_id == SWITCH_CHILD and abs(t.header.stamp.to_sec() - stamp) < 1e-6]

        t = wait_for(on_tf, f"the second registration on /tf\n{bridge.log()}")[0]
        assert t.transform.translation.x == pytest.approx(again.matrix[0, 3], abs=1e-9)
        assert SWITCH_CHILD not in static_frames(ros)
    finally:
        bridge.stop(signal.SIGTERM)
        server.stop()
    assert bridge.proc.returncode == 0, bridge.log()
