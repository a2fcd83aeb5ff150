"""arref-ros-bridge: publishes arref-server's registration results to a ROS 1 tf tree.

A client of the server's Subscribe stream: each Result of a configured robot becomes the
transform parent_frame (the headset's world) -> child_frame (the robot's base link), i.e.
T_world_base in ROS's own convention (REP 103, the server's internal frame), stamped with the
time the result's data was taken (Result.scene_time_unix_s), never the publication time.
Registrations are one-shot, so they go to /tf_static (latched; every robot's latest transform
in one message, as tf2's static broadcaster keeps them); `static: false` sends them on /tf.
Only OK results unless `publish_low_confidence`. Continuous referencing's TrackingUpdates go to
/tf as they arrive, the same frames, stamped with their frame's exposure
(TrackingUpdate.frame_time_unix_s); only the states the tracker stands behind (tracking,
reacquired, jump) unless `tracking_states` names others. It reconnects by itself and logs it.

A frame must not be on both topics: tf2 keeps a frame whose first transform came on /tf_static
in a static cache for good, and then answers every lookup, at any stamp, with the newest
transform of either topic (checked against tf2_ros: tests/test_ros_bridge.py). So a robot that
is tracked is published on /tf only: say so up front (`tracked: true` for the robot, or
`--tracked ID`), and its registrations go to /tf too. A robot found tracked without it being
said is moved to /tf then: its transform is withdrawn from /tf_static (listeners started from
then on keep it dynamic), and a warning says that listeners already running keep the static
cache until they restart.

Config (YAML, all optional; flags override):
    server: {host: 127.0.0.1, port: 7311, auth_token: "", tls_ca: ""}   # tls_ca: PEM CA of a TLS server
    world_frame: world             # parent of every robot unless a robot names its own
    static: true
    publish_low_confidence: false
    tracking_states: [tracking, reacquired, jump]
    reconnect_s: 2.0
    robots:                        # default: every robot the server serves
      - {id: kr5, parent_frame: hololens_world, child_frame: kr5_base_link, tracked: false}
"""

import argparse
import logging
import math
import signal
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from . import errors
from .client import DEFAULT_PORT, Client
from .tracking import GOOD_STATES, TrackingUpdate

# Every state a TrackingUpdate can carry (arref.proto, TrackingUpdate.state).
TRACKING_STATES = ("tracking", "rejected", "lost", "reacquired", "jump", "no_robot")

log = logging.getLogger("arref-ros-bridge")


@dataclass
class RobotFrames:
    id: str
    parent_frame: str = ""  # "": the bridge's world_frame
    child_frame: str = ""   # "": the robot's base link as the server names it
    tracked: bool = False   # every transform on /tf (see the module's help)


@dataclass
class BridgeConfig:
    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    auth_token: str = ""
    tls_ca: str = ""  # non-empty: TLS, the server verified against this PEM CA
    world_frame: str = "world"
    static: bool = True
    publish_low_confidence: bool = False
    tracking_states: tuple = GOOD_STATES  # TrackingUpdate states published on /tf
    reconnect_s: float = 2.0
    ping_s: float = 30.0  # keeps the session open past the server's idle timeout
    robots: list = field(default_factory=list)  # RobotFrames; empty: every robot served
    tracked: set = field(default_factory=set)   # ids of robots tracked (besides RobotFrames.tracked)


def load_config(path):
    import yaml  # python3-yaml, a dependency of rospy

    with open(path) as f:
        data = yaml.safe_load(f) or {}
    known = {"server", "world_frame", "static", "publish_low_confidence", "tracking_states", "reconnect_s", "robots"}
    unknown = set(data) - known
    if unknown:
        raise ValueError(f"{path}: unknown keys {sorted(unknown)} (known: {sorted(known)})")
    c = BridgeConfig()
    server = data.get("server", {}) or {}
    c.host = str(server.get("host", c.host))
    c.port = int(server.get("port", c.port))
    c.auth_token = str(server.get("auth_token", c.auth_token))
    c.tls_ca = str(server.get("tls_ca", c.tls_ca) or "")
    c.world_frame = str(data.get("world_frame", c.world_frame))
    c.static = bool(data.get("static", c.static))
    c.publish_low_confidence = bool(data.get("publish_low_confidence", c.publish_low_confidence))
    c.reconnect_s = float(data.get("reconnect_s", c.reconnect_s))
    c.tracking_states = tracking_states(data.get("tracking_states", c.tracking_states), path)
    for i, r in enumerate(data.get("robots", []) or []):
        if "id" not in r:
            raise ValueError(f"{path}: robots[{i}] has no id")
        unknown = set(r) - {"id", "parent_frame", "child_frame", "tracked"}
        if unknown:
            raise ValueError(f"{path}: robots[{i}] has unknown keys {sorted(unknown)}")
        c.robots.append(RobotFrames(str(r["id"]), str(r.get("parent_frame", "")), str(r.get("child_frame", "")),
                                    bool(r.get("tracked", False))))
    return c


def tracking_states(states, where):
    states = tuple(str(x) for x in states)
    unknown = set(states) - set(TRACKING_STATES)
    if unknown:
        raise ValueError(f"{where}: tracking_states {sorted(unknown)} unknown (known: {', '.join(TRACKING_STATES)})")
    return states


def should_publish(pushed, config):
    """A Result: OK (or LOW_CONFIDENCE if configured); a TrackingUpdate: one of tracking_states."""
    if isinstance(pushed, TrackingUpdate):
        return pushed.state in config.tracking_states
    return pushed.status == "OK" or (config.publish_low_confidence and pushed.status == "LOW_CONFIDENCE")


def quaternion_from_matrix(R):
    """(x, y, z, w) of a rotation matrix (Shepperd's method: stable for every rotation)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.trace(R)
    if t > 0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = ((R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s)
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = (0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s)
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = ((R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = ((R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s)
    q = np.array(q)
    return tuple(q / np.linalg.norm(q))


@dataclass
class Transform:
    parent: str
    child: str
    stamp_s: float
    translation: tuple
    rotation: tuple  # x, y, z, w
    dynamic: bool = False  # /tf whatever the config says (tracking); else as `static` says


def transform_of(pushed, frames):
    """The tf transform of a Result (T_world_base from its internal, ROS matrix) or of a
    TrackingUpdate (its pose in ROS's convention), stamped with the time of its data; dynamic
    for every transform of a tracked robot."""
    if isinstance(pushed, TrackingUpdate):
        p = pushed.ros_pose
        q = np.asarray(p[3:], dtype=np.float64)
        return Transform(frames.parent_frame, frames.child_frame, pushed.frame_time_unix_s, tuple(p[:3]),
                         tuple(q / np.linalg.norm(q)), dynamic=True)
    T = pushed.matrix
    stamp = pushed.proto.scene_time_unix_s
    return Transform(frames.parent_frame, frames.child_frame, stamp, tuple(T[:3, 3]), quaternion_from_matrix(T[:3, :3]),
                     dynamic=frames.tracked)


class Bridge:
    """The arref side: connects, subscribes, hands publishable transforms to `publish`."""

    def __init__(self, config, publish, is_shutdown=lambda: False):
        self.config = config
        self.publish = publish
        self.is_shutdown = is_shutdown
        self.frames = {}  # robot id -> RobotFrames with names filled in
        self._tracking = {}  # robot id -> (state, updates published, skipped) since the last log line

    def _found_tracked(self, robot_id):
        """A robot seen tracked before a reconnection stays on /tf."""
        return robot_id in self._tracking

    def _connect(self):
        c = Client(self.config.host, self.config.port, client_name="arref-ros-bridge",
                   auth_token=self.config.auth_token, timeout=30.0, tls_ca=self.config.tls_ca or None)
        served = {r.id: r for r in c.robots}
        wanted = self.config.robots or [RobotFrames(rid) for rid in served]
        self.frames = {}
        for r in wanted:
            if r.id not in served:
                log.warning("robot '%s' is not served by %s:%d (served: %s); skipped", r.id, self.config.host,
                            self.config.port, ", ".join(served))
                continue
            frames = RobotFrames(r.id, r.parent_frame or self.config.world_frame, r.child_frame or served[r.id].base_link,
                                 r.tracked or r.id in self.config.tracked or self._found_tracked(r.id))
            c.subscribe(r.id)
            self.frames[r.id] = frames
            log.info("publishing robot '%s' as %s -> %s on %s (tracking updates on /tf)", r.id, frames.parent_frame,
                     frames.child_frame, "/tf_static" if self.config.static and not frames.tracked else "/tf")
        return c

    def run(self):
        """Until is_shutdown(): serves one connection after the other, reconnecting when one drops."""
        connected_before = False
        while not self.is_shutdown():
            try:
                client = self._connect()
            except (errors.ArrefError, OSError) as e:
                log.warning("cannot reach arref-server at %s:%d (%s); retrying in %.1f s", self.config.host,
                            self.config.port, e, self.config.reconnect_s)
                self._sleep(self.config.reconnect_s)
                continue
            log.info("%s arref-server %s at %s:%d (session %d)", "reconnected to" if connected_before else "connected to",
                     client.server_version, self.config.host, self.config.port, client.session_id)
            connected_before = True
            try:
                self._serve(client)
            except (errors.ConnectionClosed, errors.Timeout, OSError) as e:
                log.warning("connection to arref-server lost (%s); reconnecting in %.1f s", e, self.config.reconnect_s)
                self._sleep(self.config.reconnect_s)
            except errors.ServerError as e:
                log.warning("arref-server ended the session: %s; reconnecting in %.1f s", e, self.config.reconnect_s)
                self._sleep(self.config.reconnect_s)
            finally:
                client.close()

    def _serve(self, client):
        last_ping = time.monotonic()
        while not self.is_shutdown():
            try:
                pushed = client.next_pushed(timeout=1.0)
            except errors.Timeout:
                if time.monotonic() - last_ping > self.config.ping_s:
                    client.ping()
                    last_ping = time.monotonic()
                continue
            frames = self.frames.get(pushed.robot_id)
            if frames is None:
                continue
            if isinstance(pushed, TrackingUpdate):
                self._on_tracking(pushed, frames)
                continue
            result = pushed
            if not should_publish(result, self.config):
                log.info("robot '%s' request %d: %s (%s): not published", result.robot_id, result.request_id,
                         result.status, result.message)
                continue
            t = transform_of(result, frames)
            if t.stamp_s <= 0:  # a server without scene times: say so rather than invent one
                log.warning("result without scene_time_unix_s (older server?): stamped with the time received")
                t.stamp_s = time.time()
            self.publish(t)
            log.info("robot '%s' request %d (session %d): %s -> %s at (%.4f, %.4f, %.4f), stamp %.3f", result.robot_id,
                     result.request_id, result.session_id, t.parent, t.child, *t.translation, t.stamp_s)

    def _on_tracking(self, u, frames):
        """Each update of a configured state on /tf; the log says when a robot's tracking state
        changes (with the counts since), not every frame."""
        state, published, skipped = self._tracking.get(u.robot_id, ("", 0, 0))
        if not frames.tracked:
            frames.tracked = True
            if self.config.static:
                log.warning("robot '%s' is tracked but was not configured as tracked: from now on its transforms go "
                            "to /tf only and it is withdrawn from /tf_static; tf listeners already running keep "
                            "%s -> %s static (answering every stamp with the newest transform) until they restart. "
                            "Set `tracked: true` for it (or --tracked %s) to avoid this.", u.robot_id,
                            frames.parent_frame, frames.child_frame, u.robot_id)
        if u.state != state:
            log.info("robot '%s' tracking (session %d): %s from frame %d (%d updates published, %d skipped so far)",
                     u.robot_id, u.session_id, u.state, u.frame_id, published, skipped)
        if not should_publish(u, self.config):
            self._tracking[u.robot_id] = (u.state, published, skipped + 1)
            return
        if u.frame_time_unix_s <= 0:  # a server before frame_time_unix_s: no data time to stamp with
            if skipped == 0 or u.state != state:
                log.warning("tracking update without frame_time_unix_s (older server?): not published")
            self._tracking[u.robot_id] = (u.state, published, skipped + 1)
            return
        self.publish(transform_of(u, frames))
        self._tracking[u.robot_id] = (u.state, published + 1, skipped)
        log.debug("robot '%s' frame %d: %s -> %s, stamp %.3f", u.robot_id, u.frame_id, frames.parent_frame,
                  frames.child_frame, u.frame_time_unix_s)

    def _sleep(self, seconds):
        end = time.monotonic() + seconds
        while not self.is_shutdown() and time.monotonic() < end:
            time.sleep(0.1)


class RosPublisher:
    """tf2_ros on rospy: static transforms latched together, dynamic ones as they come."""

    def __init__(self, static):
        import tf2_ros

        self.static = static
        self._static = tf2_ros.StaticTransformBroadcaster() if static else None
        self._dynamic = tf2_ros.TransformBroadcaster()
        self._latched = {}  # child frame -> TransformStamped: a latched topic keeps only its last message

    def __call__(self, t):
        import rospy
        from geometry_msgs.msg import TransformStamped

        m = TransformStamped()
        m.header.stamp = rospy.Time.from_sec(t.stamp_s)
        m.header.frame_id = t.parent
        m.child_frame_id = t.child
        m.transform.translation.x, m.transform.translation.y, m.transform.translation.z = t.translation
        (m.transform.rotation.x, m.transform.rotation.y, m.transform.rotation.z,
         m.transform.rotation.w) = t.rotation
        if self.static and not t.dynamic:
            self._latched[t.child] = m
            self._static.sendTransform(list(self._latched.values()))
            return
        if self._latched.pop(t.child, None) is not None:  # now dynamic: new listeners must not see it static
            self._static.sendTransform(list(self._latched.values()))
        self._dynamic.sendTransform(m)


def parser():
    p = argparse.ArgumentParser(prog="arref-ros-bridge", description=__doc__.split("\n\n")[0])
    p.add_argument("--config", help="bridge YAML (see the module's help)")
    p.add_argument("--host")
    p.add_argument("--port", type=int)
    p.add_argument("--auth-token")
    p.add_argument("--tls-ca", help="connect over TLS, verifying the server against this PEM CA")
    p.add_argument("--world-frame", help="parent frame of every robot that names none")
    p.add_argument("--robot", action="append", default=[], metavar="ID[:CHILD[:PARENT]]",
                   help="publish this robot (repeatable), optionally naming its base frame and world frame")
    p.add_argument("--dynamic", action="store_true", help="publish on /tf instead of /tf_static")
    p.add_argument("--tracked", action="append", default=[], metavar="ID",
                   help="this robot is tracked: all its transforms on /tf (repeatable)")
    p.add_argument("--publish-low-confidence", action="store_true")
    p.add_argument("--tracking-states", help="comma-separated TrackingUpdate states published on /tf "
                                             f"(default {','.join(GOOD_STATES)}; any of {', '.join(TRACKING_STATES)})")
    p.add_argument("--reconnect", type=float, help="seconds between connection attempts")
    p.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])
    return p


def config_from_args(args):
    c = load_config(args.config) if args.config else BridgeConfig()
    if args.host:
        c.host = args.host
    if args.port:
        c.port = args.port
    if args.auth_token is not None:
        c.auth_token = args.auth_token
    if args.tls_ca:
        c.tls_ca = args.tls_ca
    if args.world_frame:
        c.world_frame = args.world_frame
    if args.dynamic:
        c.static = False
    if args.publish_low_confidence:
        c.publish_low_confidence = True
    if args.reconnect:
        c.reconnect_s = args.reconnect
    if args.tracking_states:
        c.tracking_states = tracking_states(args.tracking_states.split(","), "--tracking-states")
    if args.robot:
        c.robots = []
        for spec in args.robot:
            parts = spec.split(":")
            c.robots.append(RobotFrames(parts[0], parts[2] if len(parts) > 2 else "", parts[1] if len(parts) > 1 else ""))
    c.tracked = c.tracked | set(args.tracked)
    return c


def main(argv=None):
    args = parser().parse_args(argv)
    # Its own handler on stderr (journald under systemd): rospy reconfigures the root logger.
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s arref-ros-bridge %(levelname)s: %(message)s"))
    log.addHandler(handler)
    log.propagate = False
    log.setLevel(args.log_level.upper())
    try:
        config = config_from_args(args)
    except (ValueError, OSError) as e:
        log.error("%s", e)
        return 2
    import rospy  # only here: the pure parts above are usable (and tested) without ROS

    rospy.init_node("arref_ros_bridge", anonymous=False, disable_signals=True)
    log.disabled = False  # rospy's logging.config.fileConfig disables the loggers that exist before it
    stopping = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stopping.append(True))
    bridge = Bridge(config, RosPublisher(config.static), is_shutdown=lambda: bool(stopping) or rospy.is_shutdown())
    bridge.run()
    rospy.signal_shutdown("arref-ros-bridge stopping")
    log.info("stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
