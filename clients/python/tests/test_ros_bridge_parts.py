"""The ROS bridge's parts that need no ROS: quaternions, the publish filter, its config."""

import numpy as np
import pytest

from arref_client.ros_bridge import (BridgeConfig, config_from_args, load_config, parser, quaternion_from_matrix,
                                     should_publish)


def matrix_from_quaternion(x, y, z, w):
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_quaternion_of_any_rotation_gives_the_rotation_back():
    rng = np.random.default_rng(4)
    # random ones, and the half turns where the trace is -1 and a naive formula divides by zero
    qs = list(rng.normal(size=(200, 4))) + [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    for q in qs:
        q = np.asarray(q, dtype=float) / np.linalg.norm(q)
        R = matrix_from_quaternion(*q)
        got = quaternion_from_matrix(R)
        np.testing.assert_allclose(matrix_from_quaternion(*got), R, atol=1e-12)
        assert abs(np.linalg.norm(got) - 1) < 1e-12


class FakeResult:
    def __init__(self, status):
        self.status = status


def test_only_ok_results_unless_configured():
    c = BridgeConfig()
    assert should_publish(FakeResult("OK"), c)
    assert not should_publish(FakeResult("LOW_CONFIDENCE"), c)
    assert not should_publish(FakeResult("FAILED"), c)
    c.publish_low_confidence = True
    assert should_publish(FakeResult("LOW_CONFIDENCE"), c)
    assert not should_publish(FakeResult("FAILED"), c)


def test_shipped_config_and_flags(tmp_path):
    import os

    pytest.importorskip("yaml", reason="python3-yaml reads the bridge's config")
    shipped = os.path.join(os.path.dirname(__file__), "..", "..", "..", "config", "arref-ros-bridge.yaml")
    c = load_config(shipped)
    assert c.port == 7311 and c.world_frame == "hololens_world" and c.static
    assert [(r.id, r.child_frame) for r in c.robots] == [("kr5", "base_link")]
    args = parser().parse_args(["--config", shipped, "--port", "9000", "--robot", "ur5:ur5_base:map", "--robot", "kr5",
                                "--dynamic"])
    c = config_from_args(args)
    assert c.port == 9000 and not c.static
    assert c.tls_ca == ""  # plain TCP unless asked
    assert config_from_args(parser().parse_args(["--config", shipped, "--tls-ca", "/etc/arref/ca.pem"])).tls_ca == \
        "/etc/arref/ca.pem"
    assert [(r.id, r.child_frame, r.parent_frame) for r in c.robots] == [("ur5", "ur5_base", "map"), ("kr5", "", "")]

    bad = tmp_path / "bad.yaml"
    bad.write_text("world_frmae: x\n")
    with pytest.raises(ValueError, match="world_frmae"):
        load_config(str(bad))


def tracking_update(state="tracking", frame=None, pose=(1.0, 2.0, 0.5, 0.0, 0.0, 0.6, 0.8), unix_s=1.7e9):
    from arref_client import TrackingUpdate, pb

    u = pb.TrackingUpdate(robot_id="kr5", frame_id=3, state=state, frame=frame or pb.FRAME_CONVENTION_ROS,
                          frame_time_unix_s=unix_s)
    p = u.T_world_base
    p.position.x, p.position.y, p.position.z = pose[:3]
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = pose[3:]
    return TrackingUpdate.from_proto(u)


def test_tracking_updates_in_good_states_only_unless_configured():
    c = BridgeConfig()
    assert [s for s in ("tracking", "reacquired", "jump", "rejected", "lost", "no_robot")
            if should_publish(tracking_update(s), c)] == ["tracking", "reacquired", "jump"]
    args = parser().parse_args(["--tracking-states", "tracking,rejected"])
    c = config_from_args(args)
    assert should_publish(tracking_update("rejected"), c) and not should_publish(tracking_update("jump"), c)
    with pytest.raises(ValueError, match="tracked"):
        config_from_args(parser().parse_args(["--tracking-states", "tracked"]))


def test_tracking_transform_is_dynamic_in_ros_frame_with_the_frame_time():
    from arref_client import pb
    from arref_client.ros_bridge import RobotFrames, transform_of

    frames = RobotFrames("kr5", "hololens_world", "kr5_base")
    t = transform_of(tracking_update(), frames)
    assert t.dynamic and t.stamp_s == 1.7e9 and (t.parent, t.child) == ("hololens_world", "kr5_base")
    np.testing.assert_allclose(t.translation, (1.0, 2.0, 0.5))
    np.testing.assert_allclose(t.rotation, (0.0, 0.0, 0.6, 0.8))
    # The same pose as a Unity-frame session receives it: p_unity = (-y, z, x),
    # q_unity = (-q.y, q.z, q.x, -q.w) (the inverse of the protocol's mapping).
    u = transform_of(tracking_update(frame=pb.FRAME_CONVENTION_UNITY, pose=(-2.0, 0.5, 1.0, -0.0, 0.6, 0.0, -0.8)),
                     frames)
    np.testing.assert_allclose(u.translation, t.translation)
    np.testing.assert_allclose(u.rotation, t.rotation, atol=1e-12)


class FakeRegistration:
    """What Bridge._serve hands transform_of for an OK Result."""
    status = "OK"
    robot_id, request_id, session_id, message = "kr5", 1, 1, ""
    matrix = np.eye(4)

    class proto:
        scene_time_unix_s = 1.7e9 - 5


def test_a_robot_found_tracked_moves_to_tf_for_good():
    from arref_client.ros_bridge import Bridge, RobotFrames, transform_of

    published = []
    bridge = Bridge(BridgeConfig(), published.append)
    frames = RobotFrames("kr5", "hololens_world", "kr5_base")
    assert not transform_of(FakeRegistration(), frames).dynamic  # /tf_static while nobody tracks it
    bridge._on_tracking(tracking_update(), frames)
    assert frames.tracked and published[-1].dynamic
    assert transform_of(FakeRegistration(), frames).dynamic  # registrations too, from then on
    assert bridge._found_tracked("kr5")  # and after a reconnection


def test_tracked_robots_from_config_and_flags(tmp_path):
    pytest.importorskip("yaml", reason="python3-yaml reads the bridge's config")
    from arref_client.ros_bridge import RobotFrames, transform_of

    path = tmp_path / "bridge.yaml"
    path.write_text("robots:\n  - {id: kr5, tracked: true}\n  - {id: mh5}\n")
    c = load_config(str(path))
    assert [(r.id, r.tracked) for r in c.robots] == [("kr5", True), ("mh5", False)]
    assert transform_of(FakeRegistration(), RobotFrames("kr5", "w", "b", tracked=True)).dynamic
    c = config_from_args(parser().parse_args(["--tracked", "ur5", "--tracked", "kr5"]))
    assert c.tracked == {"ur5", "kr5"} and c.robots == []  # still every robot served
    path.write_text("robots:\n  - {id: kr5, trackd: true}\n")
    with pytest.raises(ValueError, match="trackd"):
        load_config(str(path))
