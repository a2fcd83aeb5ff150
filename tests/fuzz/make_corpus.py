#!/usr/bin/env python3
"""Writes the seed corpora in tests/fuzz/corpus/ (small, hand-written inputs that reach each
target's main paths; libFuzzer grows its own working corpus from them). Session and frame
seeds are ClientMessage text encoded by protoc, so they follow proto/arref/v1/arref.proto.
Run from the repository root: python3 tests/fuzz/make_corpus.py"""
import os
import subprocess

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CORPUS = os.path.join(ROOT, "tests", "fuzz", "corpus")


def encode(text):
    return subprocess.run(["protoc", "-I", os.path.join(ROOT, "proto"), "--encode=arref.v1.ClientMessage",
                           "arref/v1/arref.proto"], input=text.encode(), capture_output=True, check=True).stdout


def varint(n):
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        out.append(b | (0x80 if n else 0))
        if not n:
            return bytes(out)


def frames(*texts):
    return b"".join(varint(len(m)) + m for m in map(encode, texts))


def write(target, name, data):
    os.makedirs(os.path.join(CORPUS, target), exist_ok=True)
    with open(os.path.join(CORPUS, target, name), "wb") as f:
        f.write(data if isinstance(data, bytes) else data.encode())


HELLO = 'hello { protocol_version: 1 client_name: "seed" }'
POSE = "position { x: 0.1 y: 0 z: 1.5 } orientation { w: 1 }"
SURFACE = ("surface_upsert { surface_id: 7 vertices: [0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1] "
           "triangles: [0, 1, 2, 0, 2, 3, 0, 3, 1, 1, 3, 2] T_world_surface { %s } frame: FRAME_CONVENTION_UNITY }" % POSE)
QUANTIZED = ("surface_upsert { surface_id: 8 quantized_vertices: [0, 0, 0, 100, 0, 0, 0, 100, 0] vertex_scale: 0.01 "
             "triangles: [0, 1, 2] T_world_surface { %s } frame: FRAME_CONVENTION_ROS }" % POSE)
SEED = "seed_pose { T_world_seed { %s } frame: FRAME_CONVENTION_UNITY }" % POSE
JOINTS = 'joint_state { robot_id: "kr5" names: ["joint_a1", "joint_a2"] positions: [0.1, -0.2] }'
REQUEST = ('register_request { request_id: 1 robot_id: "kr5" method: "arref-icp" result_frame: FRAME_CONVENTION_UNITY '
           "params { crop_radius_m: 2 scene_samples: 500 } head_path { positions { x: 0 y: 1.6 z: 0 } "
           "frame: FRAME_CONVENTION_UNITY } seed { T_world_seed { %s } frame: FRAME_CONVENTION_ROS } }" % POSE)

# session: what one headset sends on a connection.
write("session", "hello_ping", frames(HELLO, 'ping { nonce: 5 payload: "abc" }'))
write("session", "full_request", frames(HELLO, SURFACE, QUANTIZED, SEED, JOINTS, REQUEST,
                                        'subscribe { robot_id: "kr5" }', "cancel { request_id: 1 }",
                                        "surface_remove { surface_id: 7 }", "ping { nonce: 1 }"))
write("session", "request_no_scene", frames(HELLO, 'register_request { request_id: 3 robot_id: "kr5" }'))
write("session", "two_requests_cancel", frames(HELLO, SURFACE, REQUEST, REQUEST.replace("request_id: 1", "request_id: 2"),
                                               "cancel { request_id: 2 }", 'subscribe { robot_id: "kr5" unsubscribe: true }'))
write("session", "no_hello", frames(SURFACE))
write("session", "bad_version", frames('hello { protocol_version: 9 }'))
write("session", "hello_twice_unknown", frames(HELLO, HELLO, 'joint_state { robot_id: "ur5" names: ["x"] positions: [1] }',
                                               "surface_remove { surface_id: 99 }"))
write("session", "truncated", frames(HELLO, SURFACE)[:-5])
write("session", "bad_varint", frames(HELLO) + b"\xff" * 11)

# frame_decoder: byte 0 picks the body limit (x37), byte 1 the read sizes, then the stream.
stream = frames(HELLO, SURFACE, "ping { nonce: 2 }")
write("frame_decoder", "three_frames", bytes([255, 7]) + stream)
write("frame_decoder", "too_large", bytes([1, 3]) + stream)
write("frame_decoder", "bad_varint", bytes([200, 9]) + b"\x00\x01A" + b"\x80" * 12)
write("frame_decoder", "empty_frames", bytes([5, 1]) + b"\x00\x00\x00")

# server_config: the shipped config and small variations.
with open(os.path.join(ROOT, "config", "arref-server.yaml")) as f:
    write("server_config", "shipped.yaml", f.read())
write("server_config", "small.yaml", "server:\n  port: 0\n  workers: 1\nlimits:\n  max_sessions: 2\n"
      "robots:\n  - id: kr5\n    urdf: builtin\n    default_joints: {joint_a2: -0.5}\n")
write("server_config", "typo.yaml", "server:\n  prot: 1\n")

# urdf: the built-in robot and small trees using every geometry and joint type.
with open(os.path.join(ROOT, "config", "robots", "kr5_primitive.urdf")) as f:
    write("urdf", "kr5_primitive.urdf", f.read())
write("urdf", "meshes.urdf", """<robot name="m">
  <link name="base"><visual><geometry><mesh filename="t.stl" scale="2 2 2"/></geometry></visual></link>
  <link name="a"><visual><origin xyz="0 0 0.1" rpy="0 1.57 0"/><geometry><mesh filename="t.obj"/></geometry></visual>
    <collision><geometry><sphere radius="0.1"/></geometry></collision></link>
  <link name="b"><visual><geometry><mesh filename="file://t.ply"/></geometry></visual></link>
  <link name="c"><visual><geometry><cylinder radius="0.05" length="0.3"/></geometry></visual></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="j2" type="prismatic"><parent link="a"/><child link="b"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.5" effort="1" velocity="1"/></joint>
  <joint name="j3" type="continuous"><parent link="b"/><child link="c"/><axis xyz="0 1 0"/></joint>
  <joint name="j4" type="revolute"><parent link="base"/><child link="d"/><axis xyz="0 1 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/><mimic joint="j1" multiplier="-2" offset="0.1"/></joint>
  <link name="d"><visual><geometry><box size="0.1 0.2 0.3"/></geometry></visual></link>
</robot>
""")

# mesh: byte 0 picks the extension (0 .stl, 1 .ply, 2 .obj), the rest is the file.
write("mesh", "ascii.stl", b"\x00solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
      b"endloop\nendfacet\nendsolid t\n")
import struct
tri = struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0)
write("mesh", "binary.stl", b"\x00" + b"B" * 80 + struct.pack("<I", 2) + tri + tri)
write("mesh", "ascii.ply", b"\x01ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
      b"property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
      b"0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n4 0 1 3 2\n")
write("mesh", "binary.ply", b"\x01ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
      b"property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
      + struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0) + struct.pack("<B3i", 3, 0, 1, 2))
write("mesh", "quad.obj", b"\x02o q\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nvt 0 0\nf 1/1/1 2/1/1 3/1/1 4/1/1\n"
      b"g second\nv 0 0 1\nf -1 1 2\n")
