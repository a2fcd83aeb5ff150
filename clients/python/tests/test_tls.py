"""The Python client over TLS against the real arref-server, with a throwaway CA made here."""

import json
import ssl

import pytest

from arref_client import Client, errors, tls_context
from arref_client.recording import read_recording
from arref_testing import Pki, ServerProcess, python_cli
from test_client import assert_near_truth


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    return Pki(tmp_path_factory.mktemp("pki"), "good")


@pytest.fixture(scope="module")
def other_pki(tmp_path_factory):
    return Pki(tmp_path_factory.mktemp("pki_other"), "other")


@pytest.fixture(scope="module")
def tls_server(tmp_path_factory, pki):
    s = ServerProcess(tmp_path_factory.mktemp("tls_server"), tls=pki.server_tls)
    yield s
    s.stop()


def test_registration_over_tls_verifies_the_server(tls_server, pki, cell_ros):
    with Client("127.0.0.1", tls_server.port, tls_ca=pki.ca) as c:
        assert c.session_id > 0
        c.upload_mesh(cell_ros.mesh["ply"], frame="ros")
        assert_near_truth(c.register("kr5", seed=cell_ros.seed(0), frame="ros"), cell_ros)
    with Client("localhost", tls_server.port, ssl_context=tls_context(pki.ca)) as c:  # the certificate's DNS name
        assert any(r.id == "kr5" for r in c.robots)


def test_another_ca_raises_the_typed_error_and_the_server_keeps_serving(tls_server, pki, other_pki):
    with pytest.raises(errors.TlsVerificationFailed, match="certificate did not verify for 127.0.0.1"):
        Client("127.0.0.1", tls_server.port, tls_ca=other_pki.ca)
    with pytest.raises(errors.TlsVerificationFailed, match="127.0.0.2"):  # a name the certificate lacks
        Client("127.0.0.1", tls_server.port, tls_ca=pki.ca, server_hostname="127.0.0.2")
    assert tls_server.proc.poll() is None
    with Client("127.0.0.1", tls_server.port, tls_ca=pki.ca) as c:
        c.ping()
    assert "TLS handshake failed" in tls_server.log()


@pytest.mark.parametrize("name,start,end,why", [
    ("expired", "20200101000000Z", "20200102000000Z", "certificate has expired"),
    ("not_yet_valid", "20990101000000Z", "20991231000000Z", "certificate is not yet valid"),
])
def test_a_server_certificate_outside_its_dates_raises_the_typed_error_saying_why(tmp_path, pki, name, start, end,
                                                                                  why):
    s = ServerProcess(tmp_path, tls=pki.issue(name, start, end))
    try:
        with pytest.raises(errors.TlsVerificationFailed, match=f"did not verify for 127.0.0.1: {why}"):
            Client("127.0.0.1", s.port, tls_ca=pki.ca)
        assert s.proc.poll() is None
    finally:
        s.stop()


def test_plaintext_and_tls_do_not_mix(tls_server, server, pki):
    with pytest.raises(errors.ConnectionClosed):  # the TLS server closes a plaintext Hello
        Client("127.0.0.1", tls_server.port, timeout=30)
    with pytest.raises(errors.TlsError):  # a plaintext server does not answer a TLS handshake
        Client("127.0.0.1", server.port, tls_ca=pki.ca, timeout=10)


def test_cli_takes_the_ca(tls_server, pki, other_pki):
    ok = python_cli("--port", str(tls_server.port), "--tls-ca", pki.ca, "info")
    assert ok.returncode == 0, ok.stderr
    assert any(r["id"] == "kr5" for r in json.loads(ok.stdout)["robots"])
    bad = python_cli("--port", str(tls_server.port), "--tls-ca", other_pki.ca, "info")
    assert bad.returncode == 7  # no connection
    assert "certificate did not verify" in bad.stderr


def test_tracking_over_tls_reads_every_update(tls_server, pki, track_stream):
    # Tracking polls the socket: TLS may hold decrypted updates that select() does not announce.
    stream = read_recording(track_stream.path).messages
    with Client("127.0.0.1", tls_server.port, tls_ca=pki.ca) as c:
        out = c.track("kr5", stream)
    assert not out.errors, [str(e) for e in out.errors]
    assert out.updates
    assert len(out.updates) + out.frames_dropped == out.frames_sent


def test_a_server_shutting_down_ends_the_tls_session_cleanly(tmp_path, pki):
    # close_notify after the last message: ssl then reads a clean end (b""). A strict context
    # (OpenSSL's default; Python may set OP_IGNORE_UNEXPECTED_EOF) raises SSLEOFError on a cut
    # connection instead ("receiving failed: ... EOF occurred in violation of protocol").
    strict = tls_context(pki.ca)
    strict.options &= ~getattr(ssl, "OP_IGNORE_UNEXPECTED_EOF", 0)
    s = ServerProcess(tmp_path, tls=pki.server_tls)
    try:
        with Client("127.0.0.1", s.port, ssl_context=strict) as c:
            c.ping()
            s.proc.terminate()
            kinds = []
            with pytest.raises(errors.ConnectionClosed) as closed:
                while True:
                    kinds.append(c.receive(timeout=30).WhichOneof("kind"))
            assert "the server closed the connection" in str(closed.value), str(closed.value)
            assert "shutdown" in kinds, kinds
        assert s.proc.wait(timeout=60) == 0
    finally:
        s.stop()
