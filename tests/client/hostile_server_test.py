"""`wosac-eval submit` and `follow` against a server that misbehaves: a real HTTP server on 127.0.0.1 (the
standard library's, in a thread) that speaks just enough tus to take an upload, then trickles its answers
or sends answers without the fields the client needs. The client stops with one sentence naming the
server's fault: never a hang, never "a bug in wosac-eval"."""

from __future__ import annotations

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from wosac_eval.client import ProtocolError, RetryPolicy, ServerUnavailable, follow

from support.runs import run_cli

SID = "a" * 32
STATUS = {"id": SID, "state": "done", "method": "m", "progress": {"scenarios_done": 1, "scenarios_total": 1}}


class Hostile(BaseHTTPRequestHandler):
    """Takes a tus upload at once; answers the status, and the result as `self.server.result` says."""

    def log_message(self, *args) -> None:  # quiet
        pass

    def _answer(self, status: int, body: bytes = b"", **headers: str) -> None:
        self.send_response(status)
        for name, value in {"Content-Length": str(len(body)), "Tus-Resumable": "1.0.0", **headers}.items():
            self.send_header(name, value)
        self.end_headers()
        if self.server.trickle and body:  # type: ignore[attr-defined]
            for byte in body:
                self.wfile.write(bytes([byte]))
                self.wfile.flush()
                time.sleep(0.2)
        else:
            self.wfile.write(body)

    def do_POST(self) -> None:
        self._answer(201, Location=f"/v1/uploads/{'b' * 32}", **{"Upload-Offset": "0"})

    def do_PATCH(self) -> None:
        size = int(self.headers["Content-Length"])
        self.rfile.read(size)
        self._answer(204, **{"Upload-Offset": str(size), "Submission-Id": SID})

    def do_GET(self) -> None:
        if self.path.endswith("/results/summary"):
            self._answer(200, self.server.result)  # type: ignore[attr-defined]
        else:
            self._answer(200, json.dumps(STATUS).encode())


@pytest.fixture
def hostile():
    server = ThreadingHTTPServer(("127.0.0.1", 0), Hostile)
    server.trickle, server.result = False, b"{}"  # type: ignore[attr-defined]
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield server
    server.shutdown()
    server.server_close()


def url(server) -> str:
    return f"http://127.0.0.1:{server.server_address[1]}"


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_an_answer_that_trickles_stops_at_its_deadline(hostile):
    hostile.trickle = True
    start = time.monotonic()
    with pytest.raises(ServerUnavailable, match="did not come whole within 2 s") as caught:
        follow(SID, server=url(hostile), key="k", retry=RetryPolicy(answer_deadline_s=2.0))
    assert time.monotonic() - start < 10
    assert "the server or the network to it is at fault" in str(caught.value)


@pytest.mark.parametrize(
    ("result", "named"),
    [
        (b'{"challenge": "sim_agents", "config": "2025", "num_scenarios": 1}', "'buckets' (missing)"),
        (b"<html>502 Bad Gateway</html>", "not a JSON object"),
        (b'{"challenge": "sim_agents", "config": "2025", "num_scenarios": 1, "buckets": {"min_ade": "x"}}', "buckets"),
    ],
    ids=["no-buckets", "not-json", "bad-buckets"],
)
def test_a_result_without_what_the_client_needs_is_the_servers_fault(hostile, tmp_path, result, named):
    hostile.result = result
    with pytest.raises(ProtocolError, match="answer") as caught:
        follow(SID, server=url(hostile), key="k")
    assert named in str(caught.value)
    # The command line: the upload (tus) goes through, --wait meets the broken result: exit 2, one line.
    submission = tmp_path / "s.binproto"
    submission.write_bytes(b"\x3a\x03abc")
    done = run_cli(
        "submit",
        str(submission),
        "--server",
        url(hostile),
        "--key",
        "k",
        "--method",
        "m",
        "--wait",
        "--state-dir",
        str(tmp_path / "state"),
        timeout=60,
    )
    assert done.returncode == 2, done.stderr
    assert named in done.stderr and "internal error" not in done.stderr and "Traceback" not in done.stderr
