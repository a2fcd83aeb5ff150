"""Session recordings (arref-server --record-dir): read them, and send one to a live server at its
recorded pace or as fast as possible. Format: proto/arref/v1/arref.proto, "recordings"."""

import time
from dataclasses import dataclass, field

from google.protobuf.internal.decoder import _DecodeVarint

from . import errors
from ._proto import pb
from .client import Client, read_frames

FORMAT = "arref-recording"
FORMAT_VERSIONS = (1, 2)  # 2 adds answer records and RecordingHeader.start_server_time_s


@dataclass
class Recording:
    header: object                                # arref.v1.RecordingHeader
    messages: list = field(default_factory=list)  # arref.v1.RecordedMessage, in arrival order
    answered_at_s: dict = field(default_factory=dict)  # request id -> when the server sent its Result


def read_recording(path):
    """The whole file. Raises ValueError naming the file when it is not a recording."""
    with open(path, "rb") as f:
        data = f.read()
    header = pb.RecordingHeader()  # the first frame
    try:
        size, pos = _DecodeVarint(data, 0)
        header.ParseFromString(data[pos:pos + size])
    except Exception as e:
        raise ValueError(f"{path}: not an arref recording: {e}") from e
    if header.format != FORMAT:
        raise ValueError(f"{path}: not an arref recording (format '{header.format}')")
    if header.format_version not in FORMAT_VERSIONS:
        raise ValueError(f"{path}: format version {header.format_version}, this client reads "
                         f"{', '.join(map(str, FORMAT_VERSIONS))}")
    rest = data[pos + size:]
    try:
        records = list(read_frames(rest, pb.RecordedMessage))
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from e
    rec = Recording(header)
    for r in records:  # an answer record has no client message
        if not r.HasField("message") and r.answered_request_id:
            rec.answered_at_s[r.answered_request_id] = r.t_s
        else:
            rec.messages.append(r)
    return rec


@dataclass
class SendOutcome:
    session_id: int
    results: list   # RegistrationResult of every accepted request, in the order they came back
    errors: list    # ServerError of every message the server refused


def send_recording(recording, host="127.0.0.1", port=7311, pace="original", auth_token="",
                   client_name="arref-py (recording)", timeout=300.0, **tls):
    """Sends a recording (a Recording or a path) to a live server and waits for every result.

    pace: "original" keeps the recorded times between messages; "fast" sends them back to back.
    The recorded Hello is replaced by this client's own (a recording holds no token).
    tls: Client's TLS arguments (tls, tls_ca, ssl_context, server_hostname)."""
    if pace not in ("original", "fast"):
        raise ValueError(f"pace '{pace}': expected original or fast")
    if not isinstance(recording, Recording):
        recording = read_recording(recording)
    out = SendOutcome(0, [], [])
    with Client(host, port, client_name=client_name, auth_token=auth_token, timeout=timeout, **tls) as c:
        out.session_id = c.session_id
        messages = [m for m in recording.messages if m.message.WhichOneof("kind") != "hello"]
        t0 = messages[0].t_s if messages else 0.0
        start = time.monotonic()
        request_ids = []
        for m in messages:
            if pace == "original":
                delay = (m.t_s - t0) - (time.monotonic() - start)
                if delay > 0:
                    time.sleep(delay)
            if m.message.WhichOneof("kind") == "register_request":
                request_ids.append(m.message.register_request.request_id)
            c.send(m.message)
        for rid in request_ids:
            try:
                out.results.append(c.wait_result(rid, check=False))
            except errors.ServerError as e:  # refused: an Error instead of a Result
                out.errors.append(e)
        out.errors.extend(errors.error_from_message(e) for e in c.async_errors)
    return out
