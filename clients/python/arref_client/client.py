"""A blocking client of arref-server (protocol arref.v1, proto/arref/v1/arref.proto).

Poses are (x, y, z, qx, qy, qz, qw) in the frame convention named with them ("ros" or
"unity"); the server converts. Every server Error becomes a typed exception (errors.py).
"""

import collections
import itertools
import select
import socket
import ssl
import time
from dataclasses import dataclass, field

import numpy as np
from google.protobuf.internal.decoder import _DecodeVarint
from google.protobuf.internal.encoder import _VarintBytes

from . import errors
from ._proto import pb
from .mesh import Mesh, load_mesh, split_into_surfaces
from .tracking import ClockOffsetEstimator, TrackOutcome, TrackingUpdate

PROTOCOL_VERSION = pb.PROTOCOL_VERSION_CURRENT
DEFAULT_PORT = 7311

_FRAMES = {"ros": pb.FRAME_CONVENTION_ROS, "unity": pb.FRAME_CONVENTION_UNITY}


def frame_convention(frame):
    """pb.FrameConvention of "ros" / "unity" (or of a FrameConvention value)."""
    if isinstance(frame, str):
        try:
            return _FRAMES[frame.lower()]
        except KeyError:
            raise ValueError(f"frame '{frame}': expected ros or unity") from None
    if frame in (pb.FRAME_CONVENTION_ROS, pb.FRAME_CONVENTION_UNITY):
        return frame
    raise ValueError(f"frame {frame!r}: expected ros or unity")


def pose_to_proto(pose, out):
    values = [float(x) for x in pose]
    if len(values) != 7:
        raise ValueError(f"a pose is x,y,z,qx,qy,qz,qw (7 numbers), got {len(values)}")
    out.position.x, out.position.y, out.position.z = values[:3]
    out.orientation.x, out.orientation.y, out.orientation.z, out.orientation.w = values[3:]
    return out


def pose_from_proto(p):
    return (p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y, p.orientation.z,
            p.orientation.w)


def encode_frame(message):
    """The message with its varint length prefix (protobuf's delimited framing)."""
    body = message.SerializeToString()
    return _VarintBytes(len(body)) + body


def read_frames(data, message_type):
    """Every delimited message of a byte string, in order. Raises ValueError on a truncated tail."""
    pos = 0
    while pos < len(data):
        size, pos = _DecodeVarint(data, pos)
        if pos + size > len(data):
            raise ValueError(f"truncated frame at byte {pos}: {size} bytes declared, {len(data) - pos} left")
        message = message_type()
        message.ParseFromString(data[pos:pos + size])
        pos += size
        yield message


@dataclass
class RobotInfo:
    id: str
    name: str
    base_link: str
    joint_names: list
    default_positions: list


def _status_name(value):
    """A ResultStatus as the client names it: "OK", "LOW_CONFIDENCE", "FAILED", "CANCELLED"."""
    return pb.ResultStatus.Name(value).replace("RESULT_STATUS_", "")


def _internal_matrix(values):
    """T_world_base_internal (4x4 row-major) as an array; NaN when the message holds none."""
    return np.array(values, dtype=np.float64).reshape(4, 4) if len(values) == 16 else np.full((4, 4), np.nan)


@dataclass
class Candidate:
    """One instance of the robot a search of the whole map found (Result.candidates)."""
    status: str          # "OK", "LOW_CONFIDENCE"
    pose: tuple          # T_world_base as (x, y, z, qx, qy, qz, qw) in the result's frame
    matrix: np.ndarray   # the same transform in the internal (ROS) frame, 4x4
    message: str         # why it is not OK
    score: float
    margin: float
    inlier_fraction: float
    expected_error_m: float

    @classmethod
    def from_proto(cls, c):
        return cls(_status_name(c.status), pose_from_proto(c.T_world_base), _internal_matrix(c.T_world_base_internal),
                   c.message, c.score, c.margin, c.inlier_fraction, c.expected_error_m)


@dataclass
class RegistrationResult:
    request_id: int
    status: str          # "OK", "LOW_CONFIDENCE", "FAILED", "CANCELLED"
    robot_id: str
    session_id: int
    pose: tuple          # T_world_base as (x, y, z, qx, qy, qz, qw) in `frame`
    frame: str           # "ros" or "unity"
    matrix: np.ndarray   # the same transform in the internal (ROS) frame, 4x4
    message: str
    method: str
    rms_m: float
    inlier_fraction: float
    # One standard deviation of the pose's error (root mean square over the robot's points),
    # and its parts: the fit's own, the headset map's, the surface model's (Result.expected_error_m).
    expected_error_m: float
    fit_error_m: float
    map_error_m: float
    surface_error_m: float
    iterations: int
    stages: list
    server_ms: float
    # A request with no seed searched the whole map: every instance found, ranked, and the index
    # of the primary one (whose pose is the result's own); [] and -1 for a seeded request.
    candidates: list
    primary_candidate: int
    proto: object = field(repr=False)  # the arref.v1.Result message itself

    @classmethod
    def from_proto(cls, r):
        frame = {pb.FRAME_CONVENTION_ROS: "ros", pb.FRAME_CONVENTION_UNITY: "unity"}.get(r.frame, "unspecified")
        matrix = _internal_matrix(r.T_world_base_internal)
        status = _status_name(r.status)
        return cls(r.request_id, status, r.robot_id, r.session_id, pose_from_proto(r.T_world_base), frame, matrix,
                   r.message, r.method, r.rms_m, r.inlier_fraction, r.expected_error_m, r.fit_error_m,
                   r.map_error_m, r.surface_error_m, r.iterations, list(r.stages), r.server_ms,
                   [Candidate.from_proto(c) for c in r.candidates], r.primary_candidate if r.candidates else -1, r)

    @property
    def ok(self):
        return self.status == "OK"


def _pushed(message):
    if message.WhichOneof("kind") == "result":
        return RegistrationResult.from_proto(message.result)
    return TrackingUpdate.from_proto(message.tracking_update)


def tls_context(tls_ca=None, certificate=None, private_key=None):
    """An ssl.SSLContext that verifies the server's certificate and host name: against the CA file
    tls_ca (PEM), or the system's trusted CAs when it is None. certificate / private_key: this
    client's own, for a server that requires one (its tls.client_ca)."""
    context = ssl.create_default_context(cafile=tls_ca)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    if certificate:
        context.load_cert_chain(certificate, private_key)
    return context


def _wrap_tls(sock, context, server_hostname):
    try:
        return context.wrap_socket(sock, server_hostname=server_hostname)
    except ssl.SSLCertVerificationError as e:
        sock.close()
        raise errors.TlsVerificationFailed(
            f"the server's certificate did not verify for {server_hostname}: {e.verify_message}") from e
    except (ssl.SSLError, OSError) as e:  # a plaintext server, or one that refused our certificate
        sock.close()
        raise errors.TlsError(f"TLS handshake with {server_hostname} failed: {e}") from e


class Client:
    """One session with arref-server. Use as a context manager, or call close().

    TLS: tls_ca (a PEM CA file the server's certificate must be signed by), tls=True (the
    system's trusted CAs), or ssl_context (your own ssl.SSLContext). The certificate must name
    `host`, or server_hostname when given. A failed verification raises
    errors.TlsVerificationFailed."""

    def __init__(self, host="127.0.0.1", port=DEFAULT_PORT, *, client_name="arref-python", auth_token="",
                 timeout=300.0, tls=False, tls_ca=None, ssl_context=None, server_hostname=None):
        self.timeout = timeout
        try:
            sock = socket.create_connection((host, port), timeout=min(timeout, 30.0))
        except OSError as e:
            raise errors.ConnectionClosed(f"cannot connect to {host}:{port}: {e}") from e
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if ssl_context is None and (tls or tls_ca):
            ssl_context = tls_context(tls_ca)
        if ssl_context is not None:
            sock = _wrap_tls(sock, ssl_context, server_hostname or host)
        self._sock = sock
        self._rx = b""
        self._backlog = collections.deque()  # messages read while waiting for another
        self._request_ids = itertools.count(1)
        self._nonces = itertools.count(1)
        self._next_surface_id = 1
        self.async_errors = []  # Errors that answered nothing this client waited for
        self._hello(client_name, auth_token)

    # ------------------------------------------------------------ life cycle

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _hello(self, client_name, auth_token):
        m = pb.ClientMessage()
        m.hello.protocol_version = PROTOCOL_VERSION
        m.hello.client_name = client_name
        m.hello.auth_token = auth_token
        self.send(m)
        reply = self._wait(lambda s: s.WhichOneof("kind") == "hello_reply", "HelloReply")
        r = reply.hello_reply
        self.session_id = r.session_id
        self.server_version = r.server_version
        self.robots = [RobotInfo(x.id, x.name, x.base_link, list(x.joint_names), list(x.default_positions))
                       for x in r.robots]
        self.methods = list(r.methods)
        self.default_method = r.default_method

    # ------------------------------------------------------------ bytes

    def send(self, message):
        """Sends one ClientMessage."""
        self.send_raw(encode_frame(message))

    def send_raw(self, data):
        if self._sock is None:
            raise errors.ConnectionClosed("the client is closed")
        try:
            self._sock.sendall(data)
        except OSError as e:
            raise errors.ConnectionClosed(f"sending failed: {e}") from e

    def receive(self, timeout=None):
        """The next ServerMessage (backlog first). Raises Timeout or ConnectionClosed."""
        if self._backlog:
            return self._backlog.popleft()
        return self._read(self.timeout if timeout is None else timeout)

    def _read(self, timeout):
        deadline = time.monotonic() + timeout
        while True:
            if self._rx:
                try:
                    size, pos = _DecodeVarint(self._rx, 0)
                except IndexError:  # the length prefix itself is incomplete
                    size, pos = 1 << 62, 0
                if len(self._rx) >= pos + size:
                    message = pb.ServerMessage()
                    message.ParseFromString(self._rx[pos:pos + size])
                    self._rx = self._rx[pos + size:]
                    return message
            left = deadline - time.monotonic()
            if left <= 0:
                raise errors.Timeout(f"no reply from the server within {timeout:.1f} s")
            self._sock.settimeout(left)
            try:
                chunk = self._sock.recv(1 << 16)
            except socket.timeout:
                continue
            except OSError as e:
                raise errors.ConnectionClosed(f"receiving failed: {e}") from e
            if not chunk:
                raise errors.ConnectionClosed("the server closed the connection")
            self._rx += chunk

    def _wait(self, matches, what, request_id=None, timeout=None):
        """Reads until a message that `matches`; others go to the backlog. An Error for request_id,
        or a fatal one, is raised; other Errors are kept in async_errors."""
        for i, s in enumerate(self._backlog):
            if matches(s):
                del self._backlog[i]
                return s
            if request_id is not None and s.WhichOneof("kind") == "error" and s.error.request_id == request_id:
                del self._backlog[i]  # read while waiting for something else: its answer after all
                if s.error in self.async_errors:
                    self.async_errors.remove(s.error)
                raise errors.error_from_message(s.error)
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        kept = []
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise errors.Timeout(f"no {what} from the server in time")
                message = self._read(left)
                if matches(message):
                    return message
                if message.WhichOneof("kind") == "error":
                    e = message.error
                    if e.fatal or (request_id is not None and e.request_id == request_id):
                        raise errors.error_from_message(e)
                    self.async_errors.append(e)
                kept.append(message)
        finally:
            self._backlog.extend(kept)

    def sync(self, timeout=None):
        """Waits until the server has handled everything sent so far (a Ping round trip); raises the
        first Error it answered in between (e.g. BadSurface)."""
        nonce = next(self._nonces)
        m = pb.ClientMessage()
        m.ping.nonce = nonce
        before = len(self.async_errors)
        self.send(m)
        self._wait(lambda s: s.WhichOneof("kind") == "pong" and s.pong.nonce == nonce, "Pong", timeout=timeout)
        new = self.async_errors[before:]
        if new:
            del self.async_errors[before:]
            raise errors.error_from_message(new[0])

    # ------------------------------------------------------------ the spatial map

    def upload_mesh(self, mesh, frame="ros", chunk_m=1.0, timestamp_s=0.0):
        """Sends a mesh (a Mesh or a PLY/OBJ/STL path) as surfaces of chunk_m cubes in `frame`, and
        waits until the server took them. Returns the surface ids."""
        if not isinstance(mesh, Mesh):
            mesh = load_mesh(mesh)
        ids = []
        for part in split_into_surfaces(mesh, chunk_m):
            ids.append(self.upsert_surface(part.vertices, part.triangles, frame,
                                           pose=(*part.corner, 0.0, 0.0, 0.0, 1.0), timestamp_s=timestamp_s))
        self.sync()
        return ids

    def upsert_surface(self, vertices, triangles, frame, pose=(0, 0, 0, 0, 0, 0, 1), surface_id=None,
                       timestamp_s=0.0):
        """Sends one surface (no wait; errors come with the next sync()). Returns its id."""
        if surface_id is None:
            surface_id = self._next_surface_id
        self._next_surface_id = max(self._next_surface_id, surface_id + 1)
        m = pb.ClientMessage()
        s = m.surface_upsert
        s.surface_id = surface_id
        s.vertices.extend(np.asarray(vertices, dtype=np.float32).ravel().tolist())
        s.triangles.extend(np.asarray(triangles, dtype=np.int64).ravel().tolist())
        pose_to_proto(pose, s.T_world_surface)
        s.frame = frame_convention(frame)
        s.timestamp_s = timestamp_s
        self.send(m)
        return surface_id

    def remove_surface(self, surface_id):
        m = pb.ClientMessage()
        m.surface_remove.surface_id = surface_id
        self.send(m)

    def set_seed(self, pose, frame="ros", timestamp_s=0.0):
        """The session's seed: a guess of T_world_base."""
        m = pb.ClientMessage()
        pose_to_proto(pose, m.seed_pose.T_world_seed)
        m.seed_pose.frame = frame_convention(frame)
        m.seed_pose.timestamp_s = timestamp_s
        self.send(m)

    def set_joints(self, joints, robot_id="", timestamp_s=0.0):
        """The robot's joint positions by name (radians or metres)."""
        m = pb.ClientMessage()
        m.joint_state.robot_id = robot_id
        for name, value in joints.items():
            m.joint_state.names.append(name)
            m.joint_state.positions.append(float(value))
        m.joint_state.timestamp_s = timestamp_s
        self.send(m)

    # ------------------------------------------------------------ registration

    def register(self, robot_id, *, seed=None, frame="ros", joints=None, method="", result_frame=None,
                 head_path=None, gaze_point=None, wearer_position=None, request_id=None, on_progress=None,
                 check=True, timeout=None, **params):
        """Asks for a registration and waits for its Result.

        seed: a pose in `frame` for this request (default: the session's seed; with neither, the
        server searches the whole map and the result lists every instance in `candidates`).
        gaze_point, wearer_position: x, y, z in `frame`, to pick the primary instance of several.
        params: crop_radius_m, scene_samples, icp_max_correspondence_m, icp_max_iterations. With
        check, a FAILED or CANCELLED result raises RegistrationFailed / Cancelled (carrying it)."""
        rid = self.submit(robot_id, seed=seed, frame=frame, joints=joints, method=method, result_frame=result_frame,
                          head_path=head_path, gaze_point=gaze_point, wearer_position=wearer_position,
                          request_id=request_id, **params)
        return self.wait_result(rid, on_progress=on_progress, check=check, timeout=timeout)

    def submit(self, robot_id, *, seed=None, frame="ros", joints=None, method="", result_frame=None,
               head_path=None, gaze_point=None, wearer_position=None, request_id=None, **params):
        """Sends a RegisterRequest and waits for Accepted; returns its request id."""
        rid = next(self._request_ids) if request_id is None else request_id
        m = pb.ClientMessage()
        r = m.register_request
        r.request_id = rid
        r.robot_id = robot_id
        r.method = method
        if seed is not None:
            pose_to_proto(seed, r.seed.T_world_seed)
            r.seed.frame = frame_convention(frame)
        if joints:
            for name, value in joints.items():
                r.joints.names.append(name)
                r.joints.positions.append(float(value))
        if result_frame is not None:
            r.result_frame = frame_convention(result_frame)
        if head_path is not None:
            r.head_path.frame = frame_convention(frame)
            for p in np.asarray(head_path, dtype=np.float64).reshape(-1, 3):
                q = r.head_path.positions.add()
                q.x, q.y, q.z = p
        for name, point in (("gaze_point", gaze_point), ("wearer_position", wearer_position)):
            if point is not None:
                x, y, z = (float(v) for v in point)
                hint = getattr(r, name)
                hint.x, hint.y, hint.z = x, y, z
                r.hint_frame = frame_convention(frame)
        for key, value in params.items():
            if key not in ("crop_radius_m", "scene_samples", "icp_max_correspondence_m", "icp_max_iterations"):
                raise TypeError(f"register: unknown parameter '{key}'")
            setattr(r.params, key, value)
        self.send(m)
        self._wait(lambda s: s.WhichOneof("kind") == "accepted" and s.accepted.request_id == rid, "Accepted",
                   request_id=rid)
        return rid

    def wait_result(self, request_id, on_progress=None, check=True, timeout=None):
        def matches(s):
            kind = s.WhichOneof("kind")
            if kind == "progress" and s.progress.request_id == request_id:
                if on_progress:
                    on_progress(s.progress.stage, s.progress.fraction)
                return False
            return kind == "result" and s.result.request_id == request_id and s.result.session_id == self.session_id

        message = self._wait(matches, f"Result of request {request_id}", request_id=request_id, timeout=timeout)
        # Progress of this request is consumed, not kept.
        self._backlog = collections.deque(
            s for s in self._backlog
            if not (s.WhichOneof("kind") == "progress" and s.progress.request_id == request_id))
        if check and message.result.status in (pb.RESULT_STATUS_FAILED, pb.RESULT_STATUS_CANCELLED):
            raise errors.error_from_result(message.result)
        return RegistrationResult.from_proto(message.result)

    def cancel(self, request_id):
        m = pb.ClientMessage()
        m.cancel.request_id = request_id
        self.send(m)

    # ------------------------------------------------------------ other programs' results

    def subscribe(self, robot_id, unsubscribe=False):
        """Results of every request on the robot (from any session) are pushed from now on."""
        m = pb.ClientMessage()
        m.subscribe.robot_id = robot_id
        m.subscribe.unsubscribe = unsubscribe
        self.send(m)
        self._wait(lambda s: s.WhichOneof("kind") == "subscribed" and s.subscribed.robot_id == robot_id,
                   "Subscribed")

    def next_result(self, timeout=None):
        """The next Result pushed to this session (a subscription's or its own), as RegistrationResult."""
        for i, s in enumerate(self._backlog):
            if s.WhichOneof("kind") == "result":
                del self._backlog[i]
                return RegistrationResult.from_proto(s.result)
        message = self._wait(lambda s: s.WhichOneof("kind") == "result", "Result", timeout=timeout)
        return RegistrationResult.from_proto(message.result)

    def next_pushed(self, timeout=None):
        """The next Result or TrackingUpdate pushed to this session (a subscription's or its own):
        a RegistrationResult or a TrackingUpdate."""
        for i, s in enumerate(self._backlog):
            if s.WhichOneof("kind") in ("result", "tracking_update"):
                del self._backlog[i]
                return _pushed(s)
        return _pushed(self._wait(lambda s: s.WhichOneof("kind") in ("result", "tracking_update"),
                                  "Result or TrackingUpdate", timeout=timeout))

    def ping(self, payload=b""):
        """Round trip in seconds."""
        nonce = next(self._nonces)
        m = pb.ClientMessage()
        m.ping.nonce = nonce
        m.ping.payload = payload
        start = time.monotonic()
        self.send(m)
        self._wait(lambda s: s.WhichOneof("kind") == "pong" and s.pong.nonce == nonce, "Pong")
        return time.monotonic() - start

    # ------------------------------------------------------------ continuous referencing

    def sync_clock(self, exchanges=8, clock=time.time):
        """Estimates the server's clock minus `clock` from Ping/Pong round trips and reports it
        (ClockReport), so that the server reads this session's timestamps on its own clock.
        Returns (offset_s, uncertainty_s)."""
        estimator = ClockOffsetEstimator()
        for _ in range(exchanges):
            nonce = next(self._nonces)
            m = pb.ClientMessage()
            m.ping.nonce = nonce
            m.ping.client_time_s = clock()
            self.send(m)
            reply = self._wait(lambda s: s.WhichOneof("kind") == "pong" and s.pong.nonce == nonce, "Pong")
            t3 = clock()
            estimator.add(reply.pong.client_time_s, reply.pong.receive_time_s, reply.pong.server_time_s, t3)
        m = pb.ClientMessage()
        m.clock_report.offset_s = estimator.offset_s
        m.clock_report.uncertainty_s = estimator.uncertainty_s
        self.send(m)
        return estimator.offset_s, estimator.uncertainty_s

    def start_tracking(self, robot_id, seed=None, frame="ros", result_frame="ros", camera_pose_latency_s=0.0):
        """TrackRequest: this session's depth frames track the robot from `seed` (a pose in
        `frame`; None: the session's SeedPose). camera_pose_latency_s: how long after the
        exposure the device stamps its camera pose (0: at it). Waits until the server took it:
        UnknownRobot, NoSeed or InvalidArgument are raised."""
        m = pb.ClientMessage()
        m.track_request.robot_id = robot_id
        m.track_request.camera_pose_latency_s = camera_pose_latency_s
        if seed is not None:
            pose_to_proto(seed, m.track_request.seed.T_world_seed)
            m.track_request.seed.frame = frame_convention(frame)
        m.track_request.result_frame = frame_convention(result_frame)
        self.send(m)
        self.sync()

    def stop_tracking(self, robot_id):
        m = pb.ClientMessage()
        m.track_request.robot_id = robot_id
        m.track_request.stop = True
        self.send(m)

    def send_depth_frame(self, robot_id, frame_id, depth_mm, intrinsics, camera_pose, timestamp_s, frame="ros",
                         wrap_m=0.0):
        """One depth image (height x width z-depths in mm, 0: none; as uint16) with its pinhole
        intrinsics (fx, fy, cx, cy) and T_world_camera at exposure in `frame` (ROS: the optical
        frame). No wait: NotTracking / BadDepthFrame come with the next sync() or in track()."""
        depth = np.ascontiguousarray(depth_mm, dtype="<u2")
        if depth.ndim != 2:
            raise ValueError(f"depth_mm: expected a height x width array, got shape {depth.shape}")
        m = pb.ClientMessage()
        d = m.depth_frame
        d.robot_id = robot_id
        d.frame_id = frame_id
        d.height, d.width = depth.shape
        d.fx, d.fy, d.cx, d.cy = (float(v) for v in intrinsics)
        d.depth_mm = depth.tobytes()
        pose_to_proto(camera_pose, d.T_world_camera)
        d.frame = frame_convention(frame)
        d.timestamp_s = timestamp_s
        d.wrap_m = wrap_m
        self.send(m)

    def poll(self, timeout=0.0):
        """Reads what the server sent within `timeout` (at least what is already here) into the
        backlog, without blocking longer."""
        deadline = time.monotonic() + timeout
        while True:
            # Decrypted bytes already buffered by TLS are not announced by select().
            buffered = isinstance(self._sock, ssl.SSLSocket) and self._sock.pending() > 0
            readable = buffered or select.select([self._sock], [], [], max(0.0, deadline - time.monotonic()))[0]
            if not readable:
                break
            try:
                chunk = self._sock.recv(1 << 20)
            except socket.timeout:  # TLS: only part of a record was here
                break
            except OSError as e:
                raise errors.ConnectionClosed(f"receiving failed: {e}") from e
            if not chunk:
                raise errors.ConnectionClosed("the server closed the connection")
            self._rx += chunk
            deadline = time.monotonic()  # then only what is already waiting
        while True:
            try:
                self._backlog.append(self._read(0.0))
            except errors.Timeout:
                break

    def take_tracking(self):
        """The TrackingUpdates and Errors read so far (their order kept), removed from the backlog:
        (list of TrackingUpdate, list of ServerError)."""
        updates, errs, rest = [], [], collections.deque()
        for s in self._backlog:
            kind = s.WhichOneof("kind")
            if kind == "tracking_update":
                updates.append(TrackingUpdate.from_proto(s.tracking_update))
            elif kind == "error":
                if s.error in self.async_errors:
                    self.async_errors.remove(s.error)
                errs.append(errors.error_from_message(s.error))
            else:
                rest.append(s)
        self._backlog = rest
        return updates, errs

    def next_tracking_update(self, timeout=None):
        """The next TrackingUpdate pushed to this session (its own frames' or a subscription's)."""
        message = self._wait(lambda s: s.WhichOneof("kind") == "tracking_update", "TrackingUpdate", timeout=timeout)
        return TrackingUpdate.from_proto(message.tracking_update)

    def track(self, robot_id, stream, *, seed=None, frame="ros", result_frame="ros", pace="original",
              clock=time.time, on_update=None, settle_s=10.0, camera_pose_latency_s=None):
        """Tracks the robot with a stream of joint states and depth frames, and collects the updates.

        stream: (t_s, pb.ClientMessage) pairs or RecordedMessages in time order (e.g. from
        `arref simulate-track`, read with recording.read_recording), every timestamp_s on the
        stream's own clock from 0: each is sent as clock() at the start plus its own, after the
        clock is synchronised and reported, at its t_s ("original" pace) or back to back ("fast",
        where the server drops all but the newest waiting frame). A TrackRequest in the stream
        gives the seed unless `seed` (in `frame`) is given, and the device's camera pose latency
        unless camera_pose_latency_s is given (0 without either). Waits up to settle_s after the last
        frame for the updates still due, then stops tracking. Returns a TrackOutcome."""
        if pace not in ("original", "fast"):
            raise ValueError(f"pace '{pace}': expected original or fast")
        items = [(m.t_s, m.message) if hasattr(m, "t_s") else (float(m[0]), m[1]) for m in stream]
        requests = [m.track_request for _, m in items if m.WhichOneof("kind") == "track_request"]
        if seed is None:
            if not requests:
                raise ValueError("track: no seed given and no TrackRequest in the stream")
            seed = pose_from_proto(requests[0].seed.T_world_seed)
            frame = requests[0].seed.frame
        if camera_pose_latency_s is None:
            camera_pose_latency_s = requests[0].camera_pose_latency_s if requests else 0.0
        offset, uncertainty = self.sync_clock(clock=clock)
        self.start_tracking(robot_id, seed, frame=frame, result_frame=result_frame,
                            camera_pose_latency_s=camera_pose_latency_s)
        out = TrackOutcome([], 0, 0, [], offset, uncertainty, {})

        def collect():
            updates, errs = self.take_tracking()
            out.errors.extend(errs)
            for u in updates:
                if u.session_id != self.session_id or u.frame_id not in out.sent_times:
                    continue  # a subscription's, or a frame of an earlier request
                out.updates.append(u)
                out.frames_dropped = u.frames_dropped
                if on_update:
                    on_update(u)

        base = clock()
        start = time.monotonic()
        t_first = items[0][0] if items else 0.0
        for t_s, message in items:
            kind = message.WhichOneof("kind")
            if kind not in ("joint_state", "depth_frame"):
                continue
            if pace == "original":
                delay = (t_s - t_first) - (time.monotonic() - start)
                if delay > 0:
                    self.poll(delay)
                    collect()
            m = pb.ClientMessage()
            m.CopyFrom(message)
            body = getattr(m, kind)
            body.robot_id = robot_id
            body.timestamp_s = base + body.timestamp_s
            if kind == "depth_frame":
                out.sent_times[body.frame_id] = body.timestamp_s
                out.frames_sent += 1
            self.send(m)
            self.poll(0.0)
            collect()
        deadline = time.monotonic() + settle_s
        while len(out.updates) + out.frames_dropped + len(out.errors) < out.frames_sent and time.monotonic() < deadline:
            self.poll(0.05)
            collect()
        self.stop_tracking(robot_id)
        return out
