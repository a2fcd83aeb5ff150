"""The Python client against the real arref-server on loopback, on simulated cells with ground truth."""

import json
import socket

import numpy as np
import pytest

from arref_client import Client, errors, load_mesh, pb, split_into_surfaces
from arref_client.client import encode_frame
from arref_client.tracking import matrix_from_pose, pose_unity_to_ros
from arref_testing import ServerProcess, python_cli

# Success = the base within this of the truth (arref-icp lands within 1 cm on these cells; the
# bound leaves room for an unlucky seed, not for a wrong basin, which is metres off).
MAX_TRANSLATION_M = 0.03
MAX_ROTATION_DEG = 3.0


def rotation_error_deg(R_a, R_b):
    cos = (np.trace(R_a.T @ R_b) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def assert_near_truth(result, cell):
    assert result.status in ("OK", "LOW_CONFIDENCE"), result.message
    T, truth = result.matrix, cell.T_world_base
    assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < MAX_TRANSLATION_M
    assert rotation_error_deg(T[:3, :3], truth[:3, :3]) < MAX_ROTATION_DEG


def test_hello_names_the_robot_and_methods(server):
    with Client("127.0.0.1", server.port) as c:
        assert c.session_id > 0
        assert c.server_version
        kr5 = next(r for r in c.robots if r.id == "kr5")
        assert kr5.base_link
        assert len(kr5.joint_names) == 6 and len(kr5.default_positions) == 6
        assert "arref-icp" in c.methods and c.default_method in c.methods


@pytest.mark.parametrize("ext", ["ply", "obj", "stl"])
def test_mesh_formats_read_alike(cell_ros, ext):
    ply = load_mesh(cell_ros.mesh["ply"])
    other = load_mesh(cell_ros.mesh[ext])
    assert len(other.triangles) == len(ply.triangles)
    # STL stores each triangle's own corners; the surface is the same
    np.testing.assert_allclose(other.vertices[other.triangles].mean(axis=(0, 1)),
                               ply.vertices[ply.triangles].mean(axis=(0, 1)), atol=1e-4)


def test_split_keeps_every_triangle_in_its_cube(cell_ros):
    mesh = load_mesh(cell_ros.mesh["ply"])
    parts = split_into_surfaces(mesh, 1.0)
    assert sum(len(p.triangles) for p in parts) == len(mesh.triangles)
    for p in parts:
        centroids = (p.vertices[p.triangles].mean(axis=1))  # relative to the cube's corner
        assert np.all(centroids >= -1e-6) and np.all(centroids <= 1.0 + 1e-6)


def test_register_in_ros_frame_finds_the_robot(server, cell_ros):
    with Client("127.0.0.1", server.port) as c:
        ids = c.upload_mesh(cell_ros.mesh["ply"], frame="ros")
        assert len(ids) > 1
        stages = []
        r = c.register("kr5", seed=cell_ros.seed(0), frame="ros", on_progress=lambda s, f: stages.append(s))
    assert_near_truth(r, cell_ros)
    assert r.frame == "ros"
    np.testing.assert_allclose(r.pose[:3], r.matrix[:3, 3], atol=1e-9)
    assert r.robot_id == "kr5" and r.method == "arref-icp"
    assert stages and stages[-1] == "done"
    # The expected error: the map's, the fit's and the surface model's parts, added as variances
    # (a few millimetres).
    assert r.map_error_m > r.fit_error_m > 0 and r.surface_error_m > 0
    assert r.expected_error_m == pytest.approx(
        np.sqrt(r.map_error_m ** 2 + r.fit_error_m ** 2 + r.surface_error_m ** 2), rel=1e-9)
    assert 0.001 < r.expected_error_m < 0.015


def test_register_with_no_seed_lists_the_instances(server, cell_ros):
    """No seed in the request or the session: the server searches the whole map (arref-auto) and
    the result lists every instance found, the primary one's pose being the result's own."""
    with Client("127.0.0.1", server.port) as c:
        c.upload_mesh(cell_ros.mesh["ply"], frame="ros")
        truth = cell_ros.T_world_base
        r = c.register("kr5", frame="ros", gaze_point=truth[:3, 3], check=False)
    assert r.status in ("OK", "LOW_CONFIDENCE"), r.message
    assert "detect" in r.stages and r.candidates
    assert 0 <= r.primary_candidate < len(r.candidates)
    primary = r.candidates[r.primary_candidate]
    np.testing.assert_allclose(primary.matrix, r.matrix, atol=1e-9)
    assert primary.status == r.status and primary.expected_error_m > 0
    assert_near_truth(r, cell_ros)
    # A seeded request lists none.
    with Client("127.0.0.1", server.port) as c:
        c.upload_mesh(cell_ros.mesh["ply"], frame="ros")
        seeded = c.register("kr5", seed=cell_ros.seed(0), frame="ros")
    assert seeded.candidates == [] and seeded.primary_candidate == -1


def test_cli_register_with_no_seed(server, cell_ros):
    out = python_cli("--port", str(server.port), "register", "--scene", cell_ros.mesh["ply"], "--no-seed", "--json")
    assert out.returncode == 0, out.stderr
    j = json.loads(out.stdout)
    assert j["candidates"] and 0 <= j["primary_candidate"] < len(j["candidates"])
    assert j["candidates"][j["primary_candidate"]]["T_world_base"] == pytest.approx(j["T_world_base"])
    bad = python_cli("--port", str(server.port), "register", "--scene", cell_ros.mesh["ply"], "--no-seed",
                     "--seed", "0,0,0,0,0,0,1")
    assert bad.returncode != 0 and "--no-seed: give neither --seed nor --truth" in bad.stderr


def test_register_in_unity_frame_matches_ros(server, cell_ros, cell_unity):
    """The same cell written in Unity's convention: same internal pose, Unity pose = (-y, z, x)."""
    with Client("127.0.0.1", server.port) as c:
        c.upload_mesh(cell_unity.mesh["obj"], frame="unity")
        c.set_seed(cell_unity.seed(0), frame="unity")
        r = c.register("kr5", method="arref-icp-fast")
    assert r.frame == "unity"  # the seed's convention, as the protocol says
    assert_near_truth(r, cell_ros)
    # The client's Unity -> ROS mapping (the ROS bridge's, for tracking updates) is the server's.
    np.testing.assert_allclose(matrix_from_pose(pose_unity_to_ros(r.pose)), r.matrix, atol=1e-9)
    x, y, z = r.matrix[:3, 3]
    np.testing.assert_allclose(r.pose[:3], (-y, z, x), atol=1e-6)
    with Client("127.0.0.1", server.port) as c:
        c.upload_mesh(cell_ros.mesh["ply"], frame="ros")
        r_ros = c.register("kr5", seed=cell_ros.seed(0), frame="ros", method="arref-icp-fast")
    # the two files round their vertices differently (and the fit samples them), so millimetres apart
    np.testing.assert_allclose(r.matrix, r_ros.matrix, atol=0.01)


def test_errors_are_typed_and_carry_the_code(server, cell_ros):
    with Client("127.0.0.1", server.port) as c:
        with pytest.raises(errors.NoScene) as e:
            c.register("kr5", seed=cell_ros.seed(0))
        assert e.value.code == pb.ERROR_CODE_NO_SCENE and e.value.request_id > 0
        # a triangle naming a vertex the surface does not have: that surface alone is refused
        c.upsert_surface([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 7]], "ros", surface_id=41)
        with pytest.raises(errors.BadSurface) as e:
            c.sync()
        assert e.value.code == pb.ERROR_CODE_BAD_SURFACE and e.value.surface_id == 41
        c.upload_mesh(cell_ros.mesh["ply"])
        # with no seed the default method searches the whole map; a method that needs a seed
        # says so
        with pytest.raises(errors.NoSeed) as e:
            c.register("kr5", method="arref-icp")
        assert e.value.code_name == "ERROR_CODE_NO_SEED"
        with pytest.raises(errors.UnknownRobot) as e:
            c.register("no-such-robot", seed=cell_ros.seed(0))
        assert "no-such-robot" in e.value.message
        with pytest.raises(errors.InvalidArgument):
            c.register("kr5", seed=cell_ros.seed(0), method="no-such-method")
        c.ping()  # the session survived all of it


def test_wrong_version_and_token_are_fatal(server, tmp_path):
    with socket.create_connection(("127.0.0.1", server.port)) as s:
        m = pb.ClientMessage()
        m.hello.protocol_version = 99
        s.sendall(encode_frame(m))
        data = s.recv(4096)
    reply = pb.ServerMessage()
    reply.ParseFromString(data[1:1 + data[0]])
    assert reply.error.code == pb.ERROR_CODE_VERSION_MISMATCH and reply.error.fatal

    guarded = ServerProcess(tmp_path, auth_token="s3cret")
    try:
        with pytest.raises(errors.Unauthenticated) as e:
            Client("127.0.0.1", guarded.port, auth_token="wrong")
        assert e.value.fatal
        with Client("127.0.0.1", guarded.port, auth_token="s3cret") as c:
            assert c.session_id > 0
    finally:
        guarded.stop()


def test_subscriber_sees_another_sessions_result(server, cell_ros):
    with Client("127.0.0.1", server.port, client_name="watcher") as watcher:
        watcher.subscribe("kr5")
        with Client("127.0.0.1", server.port) as headset:
            headset.upload_mesh(cell_ros.mesh["ply"])
            mine = headset.register("kr5", seed=cell_ros.seed(1), method="arref-icp-fast")
            pushed = watcher.next_result(timeout=60)
            assert pushed.session_id == headset.session_id != watcher.session_id
    assert pushed.request_id == mine.request_id
    np.testing.assert_allclose(pushed.matrix, mine.matrix, atol=1e-12)


def test_cli_register_prints_json(server, cell_ros):
    out = python_cli("--port", str(server.port), "register", "--scene", cell_ros.mesh["stl"], "--truth",
                     cell_ros.truth_path, "--method", "arref-icp-fast", "--json", timeout=600)
    assert out.returncode == 0, out.stderr
    j = json.loads(out.stdout)
    T = np.array(j["T_world_base"]).reshape(4, 4)
    assert np.linalg.norm(T[:3, 3] - cell_ros.T_world_base[:3, 3]) < MAX_TRANSLATION_M
    assert j["status"] in ("OK", "LOW_CONFIDENCE")


def test_cli_names_the_servers_error(server, cell_ros):
    out = python_cli("--port", str(server.port), "register", "--scene", cell_ros.mesh["ply"], "--truth",
                     cell_ros.truth_path, "--robot", "nope", timeout=600)
    assert out.returncode == 6
    assert "ERROR_CODE_UNKNOWN_ROBOT" in out.stderr


def test_cli_bad_input_and_no_server(tmp_path, cell_ros):
    bad = tmp_path / "bad.ply"
    bad.write_text("not a mesh")
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        free = s.getsockname()[1]
    out = python_cli("--port", str(free), "info")
    assert out.returncode == 7 and "cannot connect" in out.stderr
    with pytest.raises(ValueError, match="bad.ply"):
        load_mesh(str(bad))
