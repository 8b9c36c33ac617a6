"""Slow bodies and connection floods against the real server on loopback: a refused request closes
its connection at once, a body slower than the minimum rate or past the request deadline is closed
(and frees its job slot and file), and past the global connection cap the process keeps descriptors
to spare and still answers /healthz. Real uvicorn in a subprocess, real sockets."""

from __future__ import annotations

import socket
import time

import httpx
import pytest

from support.server_harness import as_submission

# The service end to end (slow and stalled clients of a running service): the CI tier's (`pytest --ci`).
pytestmark = pytest.mark.ci

MiB = 1 << 20


def _dribble(port: int, head: str, period_s: float, limit_s: float, chunk: bytes = b"x") -> tuple[bytes, float]:
    """Send `head`, then `chunk` every `period_s` until the server closes the connection; (everything it
    sent, seconds from the headers to the close). Fails when it is still open after `limit_s`."""
    with socket.create_connection(("127.0.0.1", port)) as s:
        s.sendall(head.encode())
        return _dribble_on(s, period_s, limit_s, chunk)


def _dribble_on(s: socket.socket, period_s: float, limit_s: float, chunk: bytes = b"x") -> tuple[bytes, float]:
    started, received = time.monotonic(), b""
    s.settimeout(period_s)
    while time.monotonic() - started < limit_s:
        try:
            s.sendall(chunk)
        except OSError:  # the server closed: what it sent before is still to be read
            pass
        try:
            data = s.recv(65536)
        except socket.timeout:
            continue
        except ConnectionResetError:
            return received, time.monotonic() - started
        if not data:
            return received, time.monotonic() - started
        received += data
    raise AssertionError(f"still open after {limit_s} s; received {received[:200]!r}")


def _post_head(key: str | None, length: int) -> str:
    auth = f"Authorization: Bearer {key}\r\n" if key else ""
    return f"POST /v1/submissions HTTP/1.1\r\nHost: x\r\n{auth}Content-Length: {length}\r\n\r\n"


def test_a_refused_request_closes_its_connection_without_reading_the_body(make_server):
    server = make_server(workers=0, max_upload_bytes=MiB)
    # One byte every 0.5 s of a declared megabyte, no key: the 401 comes at once, and the close with it.
    received, took = _dribble(server.port, _post_head(None, 1_000_000), 0.5, limit_s=10)
    assert received.startswith(b"HTTP/1.1 401") and b"connection: close" in received.lower(), received
    assert took < 5, took
    key = server.key("refused")
    with socket.create_connection(("127.0.0.1", server.port)) as s:  # declared too large: 413, closed
        s.sendall(_post_head(key, 2 * MiB).encode() + b"x" * 1000)
        s.settimeout(5)
        answer = b""
        while chunk := s.recv(65536):
            answer += chunk
        assert answer.startswith(b"HTTP/1.1 413") and b"connection: close" in answer.lower(), answer

    def flood(total: int):
        for _ in range(total // 65536):
            yield b"\0" * 65536

    # A client sending as fast as it can still reads its answer, the rest of its body unread.
    with server.client("not-a-key") as c:
        r = c.post("/v1/submissions", content=flood(64 * MiB))
        assert r.status_code == 401 and r.headers["connection"] == "close", r.text
    with server.client(key) as c:
        r = c.post("/v1/submissions", content=flood(16 * MiB))  # chunked: the limit is found while reading
        assert r.status_code == 413 and r.headers["connection"] == "close", r.text
        # A bodiless error keeps its connection (nothing is left unread).
        r = c.get("/v1/submissions/" + "0" * 32)
        assert r.status_code == 404 and r.headers.get("connection") != "close"
        assert c.post("/v1/submissions", content=as_submission(b"k" * 64)).status_code == 202
    assert list((server.data_dir / "uploads").glob("*.body")) == []


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_body_slower_than_the_minimum_rate_is_closed_and_frees_its_slot_and_file(make_server):
    server = make_server(workers=0, body_grace_s=3, body_min_rate=1000, body_timeout_s=60)
    key = server.key("dribbler", max_concurrent=1)
    uploads = server.data_dir / "uploads"
    with socket.create_connection(("127.0.0.1", server.port)) as s:
        s.sendall(_post_head(key, 1_000_000).encode() + b"x")
        deadline = time.monotonic() + 2
        while not list(uploads.glob("*.body")) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(list(uploads.glob("*.body"))) == 1  # the dribble holds a file...
        with server.client(key) as c:  # ...and the key's only slot
            r = c.post("/v1/submissions", content=as_submission(b"a" * 64))
            assert r.status_code == 429, r.text
        # 4 bytes/s against a minimum of 1000: closed about when the grace ends
        received, _ = _dribble_on(s, 0.25, limit_s=10)
    assert b"408 Request Timeout" in received and b"slower than 1000 bytes/s" in received, received
    deadline = time.monotonic() + 5
    while list(uploads.glob("*.body")) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert list(uploads.glob("*.body")) == []  # ...until it is closed
    with server.client(key) as c:
        assert c.post("/v1/submissions", content=as_submission(b"b" * 64)).status_code == 202
    assert "its body came slower than 1000 bytes/s" in server.log.read_text()


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_request_past_its_deadline_is_closed_however_fast_its_body_comes(make_server):
    server = make_server(workers=0, body_grace_s=1, body_min_rate=100, request_deadline_s=3)
    key = server.key("never-ending")
    # 5 kB/s, 50 times the minimum rate, of a declared 100 MB: only the deadline ends it.
    received, took = _dribble(server.port, _post_head(key, 100_000_000), 0.2, limit_s=15, chunk=b"y" * 1000)
    assert b"408 Request Timeout" in received and b"took over 3 s" in received, received
    assert 2 < took < 9, took
    time.sleep(0.3)
    assert list((server.data_dir / "uploads").glob("*.body")) == []


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_past_the_connection_cap_the_oldest_waiting_connection_makes_room(make_server):
    # An open-file limit of 256: 64 kept aside, 2 x 64 for accept bursts, the cap is (256 - 192) / 2 = 32
    # connections; 400 half-open ones come.
    server = make_server(workers=0, nofile=256, max_connections_per_client=10_000, header_timeout_s=30)
    held = []
    try:
        for i in range(400):
            s = socket.socket()
            s.bind((f"127.0.2.{1 + i % 8}", 0))
            s.connect(("127.0.0.1", server.port))
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")  # never finished
            held.append(s)
        assert server.open_files() < 256 - 32, server.open_files()
        for _ in range(5):  # a request sent at once is served, each time in well under a second
            started = time.monotonic()
            assert httpx.get(server.url + "/healthz", timeout=10).status_code == 200
            assert time.monotonic() - started < 2
        held[0].settimeout(5)  # the first connection waited longest: it was closed to make room
        assert held[0].recv(4096).startswith(b"HTTP/1.1 503")
        still_open = 0
        for s in held[-20:]:  # the newest are still held (the cap less the 5 that made room for /healthz)
            s.setblocking(False)
            try:
                s.recv(1)  # an answer or the close: it was not held
            except BlockingIOError:
                still_open += 1
        assert still_open == 20, still_open
    finally:
        for s in held:
            s.close()
    log = server.log.read_text()
    assert "Too many open files" not in log and "out of system resource" not in log, log[-2000:]
    assert "waited longest for a request" in log


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_when_every_connection_is_busy_a_reserve_still_answers_bodiless_requests(make_server):
    # A cap of 8 with a reserve of 2: six uploads in progress fill the rest, none of them idle.
    server = make_server(workers=0, max_connections=8, body_grace_s=60)
    key = server.key("busy", max_concurrent=100)
    uploads = server.data_dir / "uploads"
    busy = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(6)]
    try:
        for s in busy:
            s.sendall(_post_head(key, 1_000_000).encode() + b"x")
        deadline = time.monotonic() + 10
        while len(list(uploads.glob("*.body"))) < 6 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(list(uploads.glob("*.body"))) == 6
        for _ in range(3):
            assert httpx.get(server.url + "/healthz", timeout=10).status_code == 200
        # A body still to come would hold a reserve place: refused (one that came whole with its
        # headers holds nothing and is served like a bodiless request).
        received, took = _dribble(server.port, _post_head(key, 1_000_000), 0.2, limit_s=5)
        assert received.startswith(b"HTTP/1.1 503") and b"connection limit" in received, received
        for s in busy:  # the uploads go on
            s.setblocking(False)
            try:
                s.recv(1)
                raise AssertionError("a busy upload was closed")
            except BlockingIOError:
                pass
    finally:
        for s in busy:
            s.close()
