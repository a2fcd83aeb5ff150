"""Continuous referencing (arref.proto, "continuous referencing"): the sender's clock against the
server's, TrackingUpdate as a Python object, and simulated streams (`arref simulate-track`)."""

import json
import math
from dataclasses import dataclass, field

import numpy as np

from ._proto import pb

# The states whose pose the tracker stands behind (it keeps them as its last good pose); the
# others (rejected, lost, no_robot) carry the filter's prediction or the seed.
GOOD_STATES = ("tracking", "reacquired", "jump")

_FRAME_NAMES = {pb.FRAME_CONVENTION_ROS: "ros", pb.FRAME_CONVENTION_UNITY: "unity"}


def matrix_from_pose(pose):
    """4x4 of (x, y, z, qx, qy, qz, qw); the quaternion is normalised."""
    x, y, z, qx, qy, qz, qw = (float(v) for v in pose)
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
    T = np.eye(4)
    T[:3, :3] = [[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
                 [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
                 [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]]
    T[:3, 3] = (x, y, z)
    return T


def pose_unity_to_ros(pose):
    """A pose in Unity's convention in ROS's, as the server converts (arref.proto, "Units and
    frames"): p_ros = (z, -x, y), q_ros = (q.z, -q.x, q.y, -q.w)."""
    x, y, z, qx, qy, qz, qw = (float(v) for v in pose)
    return (z, -x, y, qz, -qx, qy, -qw)


class ClockOffsetEstimator:
    """The server's clock minus this sender's, from Ping/Pong round trips (NTP's on-wire offset);
    the exchange with the shortest round trip among the last `keep` wins, as in core/track."""

    def __init__(self, keep=16):
        self.keep = keep
        self._exchanges = []  # (round trip, offset)

    def add(self, t0, t1, t2, t3):
        """t0 sent and t3 received on the sender's clock, t1 received and t2 sent on the server's."""
        if not all(math.isfinite(t) for t in (t0, t1, t2, t3)) or t3 < t0 or t2 < t1:
            raise ValueError(f"clock exchange out of order: t0 {t0} t1 {t1} t2 {t2} t3 {t3}")
        round_trip = (t3 - t0) - (t2 - t1)
        self._exchanges = (self._exchanges + [(round_trip, ((t1 - t0) + (t2 - t3)) / 2.0)])[-self.keep:]

    @property
    def ready(self):
        return bool(self._exchanges)

    def _best(self):
        if not self._exchanges:
            raise ValueError("no clock exchange yet")
        return min(self._exchanges)

    @property
    def offset_s(self):
        return self._best()[1]

    @property
    def uncertainty_s(self):
        return max(0.0, self._best()[0]) / 2.0


@dataclass
class TrackingUpdate:
    robot_id: str
    session_id: int
    frame_id: int
    state: str               # tracking, rejected, lost, reacquired, jump, no_robot
    pose: tuple              # filtered T_world_base as (x, y, z, qx, qy, qz, qw) in `frame`
    frame: str               # "ros" or "unity"
    matrix: np.ndarray       # the same pose as a 4x4 (in `frame`'s convention)
    frame_time_s: float      # the frame's exposure on the server's clock
    frame_time_unix_s: float  # the same on the server's wall clock (Unix time)
    covariance: np.ndarray   # 4x4 of (x, y, z, yaw), ROS frame, m and rad
    joints: dict             # the joint state the frame was registered with
    joint_staleness_s: float
    process_ms: float
    latency_ms: float
    frames_processed: int
    frames_dropped: int
    agreement: float
    depth_noise: float       # the depth's noise the server measured, sigma / range (0: not measured yet)
    proto: object = field(repr=False)  # the arref.v1.TrackingUpdate message itself

    @classmethod
    def from_proto(cls, u):
        p = u.T_world_base
        pose = (p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y, p.orientation.z,
                p.orientation.w)
        covariance = np.array(u.covariance, dtype=np.float64).reshape(4, 4) if len(u.covariance) == 16 else np.full(
            (4, 4), np.nan)
        return cls(u.robot_id, u.session_id, u.frame_id, u.state, pose, _FRAME_NAMES.get(u.frame, "unspecified"),
                   matrix_from_pose(pose) if any(pose[3:]) else np.full((4, 4), np.nan), u.frame_time_s,
                   u.frame_time_unix_s, covariance, dict(zip(u.joints.names, u.joints.positions)),
                   u.joint_staleness_s, u.process_ms, u.latency_ms, u.frames_processed, u.frames_dropped,
                   u.agreement, u.depth_noise, u)

    @property
    def ros_pose(self):
        """pose in ROS's convention (REP 103), whichever frame the tracking session asked for."""
        return pose_unity_to_ros(self.pose) if self.frame == "unity" else self.pose

    @property
    def good(self):
        """The tracker stands behind this pose (state tracking, reacquired or jump)."""
        return self.state in GOOD_STATES


@dataclass
class TrackOutcome:
    updates: list          # TrackingUpdate of this session's frames, in the order they came
    frames_sent: int
    frames_dropped: int    # as the server last reported (replaced before they were processed)
    errors: list           # ServerError of every message the server refused meanwhile
    clock_offset_s: float  # the server's clock minus the sender's, as reported
    clock_uncertainty_s: float
    sent_times: dict       # frame id -> its timestamp_s as sent (the sender's clock)


@dataclass
class TrackTruth:
    """`arref simulate-track --truth-out`: the truth of every frame of a stream."""
    robot_id: str
    jump_time_s: float
    seed: list             # the stream's TrackRequest seed, ROS frame
    frames: dict           # frame id -> {"t_s", "after_jump", "T_world_base" (4x4), "joints"}

    @classmethod
    def load(cls, path):
        with open(path) as f:
            data = json.load(f)
        frames = {}
        for f in data["frames"]:
            frames[int(f["frame_id"])] = {"t_s": f["t_s"], "after_jump": f["after_jump"], "joints": f["joints"],
                                          "T_world_base": np.array(f["T_world_base"], dtype=np.float64).reshape(4, 4)}
        return cls(data["robot_id"], data["jump_time_s"], data["seed"], frames)


def pose_error(T, truth):
    """(translation error m, yaw error rad) of a 4x4 pose against the truth, both ROS frame."""
    translation = float(np.linalg.norm(T[:3, 3] - truth[:3, 3]))
    R = truth[:3, :3].T @ T[:3, :3]
    return translation, abs(math.atan2(R[1, 0], R[0, 0]))
