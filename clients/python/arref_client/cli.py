"""arref-py: a small command line over the Python client (python3 -m arref_client --help).

Exit codes: 0 OK or LOW_CONFIDENCE (track: updates came and no Error); 1 FAILED or CANCELLED
(track: no update, or an Error); 2 bad command line; 3 a file or
value is malformed; 6 the server answered an Error (its code name is printed); 7 no connection.
"""

import argparse
import json
import math
import sys

from . import errors
from .client import DEFAULT_PORT, Client
from .tracking import TrackTruth, pose_error

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_BAD_INPUT, EXIT_SERVER_ERROR, EXIT_NO_CONNECTION = 0, 1, 2, 3, 6, 7


def _pose(text):
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not x,y,z,qx,qy,qz,qw") from None
    if len(values) != 7:
        raise argparse.ArgumentTypeError(f"'{text}' has {len(values)} numbers, a pose has 7 (x,y,z,qx,qy,qz,qw)")
    return values


def _seed_and_frame(args):
    """The seed and its frame: --seed in --frame, else the truth file's seeds[--seed-index] in its
    frame; none with --no-seed (the server searches the whole map)."""
    if args.no_seed:
        if args.seed is not None or args.truth:
            raise ValueError("--no-seed: give neither --seed nor --truth")
        return None, args.frame
    if args.seed is not None:
        return args.seed, args.frame
    if not args.truth:
        raise ValueError("no seed: pass --seed x,y,z,qx,qy,qz,qw, --truth FILE (arref simulate's truth JSON) "
                         "or --no-seed (search the whole map)")
    with open(args.truth) as f:
        truth = json.load(f)
    seeds = truth.get("seeds", [])
    if not 0 <= args.seed_index < len(seeds):
        raise ValueError(f"--seed-index {args.seed_index}: {args.truth} has {len(seeds)} seeds")
    return seeds[args.seed_index], truth.get("frame", "ros")


def _result_json(r):
    return {"request_id": r.request_id, "status": r.status, "robot_id": r.robot_id, "session_id": r.session_id,
            "frame": r.frame, "position": list(r.pose[:3]), "orientation": list(r.pose[3:]),
            "T_world_base": r.matrix.ravel().tolist(), "message": r.message, "method": r.method, "rms_m": r.rms_m,
            "inlier_fraction": r.inlier_fraction, "expected_error_m": r.expected_error_m, "iterations": r.iterations, "stages": r.stages,
            "server_ms": r.server_ms, "primary_candidate": r.primary_candidate,
            "candidates": [{"status": c.status, "position": list(c.pose[:3]), "orientation": list(c.pose[3:]),
                            "T_world_base": c.matrix.ravel().tolist(), "message": c.message, "score": c.score,
                            "margin": c.margin, "inlier_fraction": c.inlier_fraction,
                            "expected_error_m": c.expected_error_m} for c in r.candidates]}


def _tls(args):
    return {"tls": args.tls, "tls_ca": args.tls_ca, "server_hostname": args.tls_server_name}


def _connect(args):
    return Client(args.host, args.port, client_name="arref-py", auth_token=args.auth_token, timeout=args.timeout,
                  **_tls(args))


def cmd_info(args):
    with _connect(args) as c:
        print(json.dumps({"server_version": c.server_version, "session_id": c.session_id,
                          "methods": c.methods, "default_method": c.default_method,
                          "robots": [vars(r) for r in c.robots]}, indent=2))
    return EXIT_OK


def cmd_register(args):
    seed, seed_frame = _seed_and_frame(args)
    with _connect(args) as c:
        ids = c.upload_mesh(args.scene, frame=args.frame)
        print(f"uploaded {args.scene} as {len(ids)} surfaces ({args.frame} frame)", file=sys.stderr)
        progress = (lambda stage, f: print(f"{stage} {f * 100:.0f} %", file=sys.stderr)) if not args.json else None
        r = c.register(args.robot, seed=seed, frame=seed_frame, method=args.method, result_frame=args.frame,
                       on_progress=progress, check=False)
    if args.json:
        print(json.dumps(_result_json(r), indent=2))
    else:
        print(f"request {r.request_id}: {r.status}{' (' + r.message + ')' if r.message else ''}")
        print(f"  T_world_base ({r.frame}): position {r.pose[:3]} orientation {r.pose[3:]}")
        print(f"  {r.method}: rms {r.rms_m * 1e3:.1f} mm, inliers {r.inlier_fraction * 100:.1f} %, "
              f"{r.iterations} iterations, {r.server_ms:.0f} ms on the server")
        if r.expected_error_m > 0:
            print(f"  expected error {r.expected_error_m * 1e3:.1f} mm (the fit {r.fit_error_m * 1e3:.1f} mm, "
                  f"the map {r.map_error_m * 1e3:.1f} mm, the surface model {r.surface_error_m * 1e3:.1f} mm)")
        for i, c in enumerate(r.candidates):
            mark = "*" if i == r.primary_candidate else " "
            print(f"  {mark} instance {i}: {c.status} at {c.pose[:3]}, score {c.score:.3f}, margin {c.margin:.3f}, "
                  f"expected error {c.expected_error_m * 1e3:.1f} mm")
    return EXIT_OK if r.status in ("OK", "LOW_CONFIDENCE") else EXIT_FAILED


def cmd_subscribe(args):
    with _connect(args) as c:
        c.subscribe(args.robot)
        print(f"subscribed to {args.robot}", file=sys.stderr)
        seen = 0
        while args.count == 0 or seen < args.count:
            try:
                r = c.next_result(timeout=args.wait)
            except errors.Timeout:
                c.ping()  # keeps the session open past the server's idle timeout
                continue
            print(json.dumps(_result_json(r)), flush=True)
            seen += 1
    return EXIT_OK


def cmd_send_recording(args):
    from .recording import send_recording

    out = send_recording(args.file, args.host, args.port, pace="fast" if args.fast else "original",
                         auth_token=args.auth_token, timeout=args.timeout, **_tls(args))
    for e in out.errors:
        print(f"server error {e}", file=sys.stderr)
    for r in out.results:
        print(json.dumps(_result_json(r)))
    return EXIT_OK if all(r.status in ("OK", "LOW_CONFIDENCE") for r in out.results) else EXIT_FAILED


def _update_json(u, truth):
    out = {"frame_id": u.frame_id, "state": u.state, "frame": u.frame, "position": list(u.pose[:3]),
           "orientation": list(u.pose[3:]), "frame_time_unix_s": u.frame_time_unix_s, "agreement": u.agreement,
           "depth_noise": u.depth_noise, "process_ms": u.process_ms, "latency_ms": u.latency_ms, "frames_dropped": u.frames_dropped}
    if truth is not None and u.frame_id in truth.frames and u.frame == "ros":
        error_m, yaw_rad = pose_error(u.matrix, truth.frames[u.frame_id]["T_world_base"])
        out["error_mm"], out["yaw_error_deg"] = error_m * 1e3, math.degrees(yaw_rad)
    return out


def cmd_track(args):
    from .recording import read_recording

    stream = read_recording(args.stream).messages
    truth = TrackTruth.load(args.truth) if args.truth else None
    with _connect(args) as c:
        out = c.track(args.robot, stream, seed=args.seed, frame=args.frame, result_frame="ros",
                      pace="fast" if args.fast else "original",
                      on_update=lambda u: print(json.dumps(_update_json(u, truth)), flush=True))
    for e in out.errors:
        print(f"server error {e}", file=sys.stderr)
    good = sum(u.good for u in out.updates)
    summary = (f"{out.frames_sent} frames sent, {len(out.updates)} updates ({good} tracking, reacquired or jump), "
               f"{out.frames_dropped} dropped; clock offset {out.clock_offset_s:.6f} s +- "
               f"{out.clock_uncertainty_s * 1e3:.2f} ms")
    if truth is not None:
        errors_mm = sorted(1e3 * pose_error(u.matrix, truth.frames[u.frame_id]["T_world_base"])[0]
                           for u in out.updates if u.frame_id in truth.frames)
        if errors_mm:
            summary += f"; base error vs truth median {errors_mm[len(errors_mm) // 2]:.1f} mm"
    print(summary, file=sys.stderr)
    return EXIT_OK if out.updates and not out.errors else EXIT_FAILED


def parser():
    p = argparse.ArgumentParser(prog="arref-py", description="Python client of arref-server")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=DEFAULT_PORT)
    p.add_argument("--auth-token", default="", help="the server's auth_token, if it has one")
    p.add_argument("--timeout", type=float, default=300.0, help="give up waiting for a reply after this many s")
    p.add_argument("--tls", action="store_true", help="connect over TLS, verifying the server against the system's CAs")
    p.add_argument("--tls-ca", help="connect over TLS, verifying the server's certificate against this PEM CA file")
    p.add_argument("--tls-server-name", help="the name the server's certificate must carry (default: --host)")
    sub = p.add_subparsers(dest="command", required=True)

    sub.add_parser("info", help="the server's version, robots and methods").set_defaults(run=cmd_info)

    r = sub.add_parser("register", help="upload a mesh file, seed, register, print the result")
    r.add_argument("--scene", required=True, help="PLY, OBJ or STL mesh of the headset's world")
    r.add_argument("--frame", choices=["ros", "unity"], default="ros", help="convention of --scene, --seed, output")
    r.add_argument("--seed", type=_pose, help="seed x,y,z,qx,qy,qz,qw in --frame")
    r.add_argument("--truth", help="arref simulate's truth JSON: its seeds[--seed-index] is the seed")
    r.add_argument("--seed-index", type=int, default=0)
    r.add_argument("--no-seed", action="store_true", help="send no seed: the server searches the whole map")
    r.add_argument("--robot", default="kr5", help="robot id served by the server")
    r.add_argument("--method", default="", help="registration method (default: the server's)")
    r.add_argument("--json", action="store_true", help="print the result as JSON")
    r.set_defaults(run=cmd_register)

    s = sub.add_parser("subscribe", help="print every result on a robot as a JSON line")
    s.add_argument("--robot", default="kr5")
    s.add_argument("--count", type=int, default=0, help="stop after this many results (0: never)")
    s.add_argument("--wait", type=float, default=30.0, help="ping the server after this long without a result, s")
    s.set_defaults(run=cmd_subscribe)

    x = sub.add_parser("send-recording", help="send a recorded session (arref-server --record-dir) to a server")
    x.add_argument("file")
    x.add_argument("--fast", action="store_true", help="as fast as possible instead of the recorded pace")
    x.set_defaults(run=cmd_send_recording)

    t = sub.add_parser("track", help="track a robot with a stream of depth frames and joint states (arref "
                                     "simulate-track), print each update as a JSON line")
    t.add_argument("--stream", required=True, help="the stream: a recording of JointState and DepthFrame messages")
    t.add_argument("--truth", help="arref simulate-track's truth JSON: each update's error against it")
    t.add_argument("--robot", default="kr5", help="robot id served by the server")
    t.add_argument("--seed", type=_pose, help="seed x,y,z,qx,qy,qz,qw in --frame (default: the stream's TrackRequest)")
    t.add_argument("--frame", choices=["ros", "unity"], default="ros", help="convention of --seed")
    t.add_argument("--fast", action="store_true", help="as fast as possible instead of the stream's pace")
    t.set_defaults(run=cmd_track)
    return p


def main(argv=None):
    args = parser().parse_args(argv)
    try:
        return args.run(args)
    except errors.ConnectionClosed as e:
        print(f"arref-py: {e}", file=sys.stderr)
        return EXIT_NO_CONNECTION
    except errors.ServerError as e:
        print(f"arref-py: server error {e}", file=sys.stderr)
        return EXIT_SERVER_ERROR
    except errors.Timeout as e:
        print(f"arref-py: {e}", file=sys.stderr)
        return EXIT_NO_CONNECTION
    except (ValueError, OSError) as e:
        print(f"arref-py: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
