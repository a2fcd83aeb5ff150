"""Test helpers: the real arref-server process on a free loopback port, and simulated cells with
ground truth written by the real `arref simulate`. The build tree comes from ARREF_BINARY_DIR
(CTest sets it) or ./build."""

import json
import os
import subprocess
import sys
import time

import numpy as np

SOURCE_DIR = os.environ.get("ARREF_SOURCE_DIR",
                            os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", "..")))
BINARY_DIR = os.environ.get("ARREF_BINARY_DIR", os.path.join(SOURCE_DIR, "build"))
SERVER = os.path.join(BINARY_DIR, "server", "arref-server")
ARREF = os.path.join(BINARY_DIR, "clients", "cli", "arref")
# The servers under test are sanitized (scripts/test.sh --sanitize sets ARREF_SANITIZED): several
# times slower, so a live tracking session drops most frames; tests check such a server's
# tracking updates, not their accuracy.
SANITIZED = bool(os.environ.get("ARREF_SANITIZED"))
MOCK_HEADSET = os.path.join(BINARY_DIR, "clients", "mock_headset", "arref-mock-headset")


def server_yaml(auth_token="", record_dir="", port=0, tls=None):
    lines = ["server:", "  address: 127.0.0.1", f"  port: {port}", "  workers: 2", "  idle_timeout_s: 300",
             f"  auth_token: \"{auth_token}\""]
    if record_dir:
        lines.append(f"  record_dir: \"{record_dir}\"")
    if tls:
        lines.append("tls:")
        lines += [f"  {key}: \"{value}\"" for key, value in tls.items()]
    lines += ["robots:", "  - id: kr5", "    urdf: builtin"]
    return "\n".join(lines) + "\n"


class ServerProcess:
    """arref-server with a test config; its port is read from the 'listening on' line."""

    def __init__(self, tmp_path, auth_token="", record_dir="", port=0, extra_args=(), tls=None):
        self.config = tmp_path / f"server_{time.monotonic_ns()}.yaml"
        self.config.write_text(server_yaml(auth_token, record_dir, port, tls))
        self.log_path = tmp_path / f"server_{time.monotonic_ns()}.log"
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen([SERVER, "--config", str(self.config), *extra_args], stdout=subprocess.PIPE,
                                     stderr=self._log, text=True)
        line = self.proc.stdout.readline()  # blocks until the server listens or exits
        if not line.startswith("listening on "):
            log = self.log()
            self.stop()
            raise RuntimeError(f"arref-server did not start: {line!r}; log:\n{log}")
        self.port = int(line.strip().rsplit(":", 1)[1])

    def log(self):
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()


class Cell:
    """A simulated cell: mesh files in several formats, the truth JSON and its frame."""

    def __init__(self, folder, frame, rng_seed):
        self.folder = folder
        self.frame = frame
        self.mesh = {}
        for ext in ("ply", "obj", "stl"):
            self.mesh[ext] = str(folder / f"scene_{frame}.{ext}")
        self.truth_path = str(folder / f"truth_{frame}.json")
        for ext, path in self.mesh.items():
            truth = self.truth_path if ext == "ply" else str(folder / f"truth_{frame}_{ext}.json")
            subprocess.run([ARREF, "--log-level", "warn", "simulate", "--rng-seed", str(rng_seed), "--frame", frame,
                            "--mesh-out", path, "--truth-out", truth], check=True)
        with open(self.truth_path) as f:
            self.truth = json.load(f)

    @property
    def T_world_base(self):
        """The true transform, internal (ROS) frame, 4x4."""
        return np.array(self.truth["T_world_base"], dtype=np.float64).reshape(4, 4)

    def seed(self, index=0):
        return self.truth["seeds"][index]


class Pki:
    """A throwaway CA and a server certificate it signed for localhost and 127.0.0.1, made with
    Debian's openssl command line (P-256 keys: quick)."""

    def __init__(self, folder, name="test"):
        def path(suffix):
            return str(folder / f"{name}_{suffix}")

        ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
        self.ca, self.cert, self.key = path("ca.pem"), path("server.pem"), path("server.key")
        with open(path("ext.cnf"), "w") as f:
            f.write("subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
                    "extendedKeyUsage=serverAuth\n")
        self._path = path
        run = lambda *a: subprocess.run(["openssl", *a], check=True, capture_output=True)  # noqa: E731
        run("req", "-x509", *ec, "-keyout", path("ca.key"), "-out", self.ca, "-days", "2", "-subj",
            f"/CN=arref test CA {name}")
        run("req", *ec, "-keyout", self.key, "-out", path("server.csr"), "-subj", "/CN=localhost")
        run("x509", "-req", "-in", path("server.csr"), "-CA", self.ca, "-CAkey", path("ca.key"), "-CAcreateserial",
            "-out", self.cert, "-days", "2", "-extfile", path("ext.cnf"))
        # `openssl ca` (unlike `x509 -req`) sets any validity dates: its database, for issue().
        with open(path("ca.cnf"), "w") as f:
            f.write(f"[ca]\ndefault_ca = test\n[test]\ndatabase = {path('ca_index.txt')}\nnew_certs_dir = {folder}\n"
                    f"serial = {path('ca_serial')}\ndefault_md = sha256\npolicy = any\nunique_subject = no\n"
                    "[any]\ncommonName = supplied\n")
        open(path("ca_index.txt"), "w").close()
        with open(path("ca_serial"), "w") as f:
            f.write("1000\n")
        self._ec, self._run = ec, run

    def issue(self, name, start, end):
        """A server certificate (localhost, 127.0.0.1) from this CA valid only from start to end
        (YYYYMMDDHHMMSSZ): expired or not yet valid. Returns the server config's tls section."""
        cert, key, csr = self._path(f"{name}.pem"), self._path(f"{name}.key"), self._path(f"{name}.csr")
        self._run("req", *self._ec, "-keyout", key, "-out", csr, "-subj", "/CN=localhost")
        self._run("ca", "-batch", "-notext", "-config", self._path("ca.cnf"), "-cert", self.ca, "-keyfile",
                  self._path("ca.key"), "-in", csr, "-out", cert, "-startdate", start, "-enddate", end, "-extfile",
                  self._path("ext.cnf"))
        return {"certificate_chain": cert, "private_key": key}

    @property
    def server_tls(self):
        """The server config's tls section."""
        return {"certificate_chain": self.cert, "private_key": self.key}


def python_cli(*args, **kwargs):
    """Runs `python3 -m arref_client ARGS` with this interpreter and environment."""
    return subprocess.run([sys.executable, "-m", "arref_client", *args], capture_output=True, text=True, **kwargs)


class TrackStream:
    """A simulated tracking stream with ground truth, written by the real `arref simulate-track`
    (the C++ track simulator the mock headset streams): a recording of joint states and depth
    frames, and the true T_world_base of every frame."""

    def __init__(self, folder, rng_seed, seconds=3.0, jump_at=100.0, kind="long-throw", declared_latency_ms=0.0):
        """declared_latency_ms > 0: every camera pose is that late, and the stream's TrackRequest says so."""
        name = f"track_{rng_seed}" + (f"_late{declared_latency_ms:g}" if declared_latency_ms else "")
        self.path = str(folder / f"{name}.arrec")
        self.truth_path = str(folder / f"{name}_truth.json")
        late = ["--pose-latency-ms", str(declared_latency_ms), "--declare-latency"] if declared_latency_ms else []
        subprocess.run([ARREF, "--log-level", "warn", "simulate-track", "--rng-seed", str(rng_seed), "--seconds",
                        str(seconds), "--jump-at", str(jump_at), "--kind", kind, "--stream-out", self.path,
                        "--truth-out", self.truth_path] + late, check=True)
