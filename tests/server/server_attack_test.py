"""The service under attack, on loopback: expansion bombs, slow clients, connection floods, quota
dodges, name impersonation, racing upload requests, foreign bodies and key guessing. Real server
(uvicorn in a subprocess, real SQLite, real worker processes), real sockets."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import threading
import time

import pytest

from support.bombs import empty_rollouts_bomb, empty_trajectories_bomb, members_bomb, tar_stream, zeros_bomb
from support.runs import WOSAC_SERVER
from support.server_harness import as_submission, tar_bytes

# The service end to end (the red team's attacks on a running service): the CI tier's (`pytest --ci`).
pytestmark = pytest.mark.ci

MiB = 1 << 20


def _listed(c) -> list[dict]:
    return c.get("/v1/submissions").json()["submissions"]


def _usage(c, submission_id: str, timeout: float = 10.0) -> dict:
    """A finished job's status once its worker recorded what the scoring process used (just after the
    outcome, when the process has ended)."""
    deadline = time.monotonic() + timeout
    while (status := c.get(f"/v1/submissions/{submission_id}").json())["peak_rss_bytes"] is None:
        assert time.monotonic() < deadline, status
        time.sleep(0.05)
    return status


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_expansion_bombs_are_refused_at_upload_and_nothing_is_kept(make_server):
    server = make_server(workers=0, max_archive_members=100)
    with server.client(server.key("bomber")) as c:
        for kind in ("bz2", "xz", "gz"):
            bomb = zeros_bomb(kind, 128 * MiB)  # 180 B of bzip2 for 128 MiB: past the 64 MiB ratio floor
            r = c.post("/v1/submissions", content=bomb)
            assert r.status_code == 422, (kind, r.text)
            assert "max_compression_ratio" in r.json()["detail"] and "zeros.binproto" in r.json()["detail"]
        r = c.post("/v1/submissions", content=members_bomb(200))
        assert r.status_code == 422 and "max_members=100" in r.json()["detail"], r.text
        assert _listed(c) == []
    assert list((server.data_dir / "uploads").iterdir()) == []
    assert list((server.data_dir / "submissions").iterdir()) == []


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_message_bombs_fail_their_job_with_bounded_memory(make_server, scoring_data):
    server = make_server(workers=1, scenarios=scoring_data.scenarios)
    with server.client(server.key("message-bomber")) as c:
        for bomb in (empty_rollouts_bomb(8_000_000), empty_trajectories_bomb(8_000_000)):  # 16 kB, 16 MB inside
            r = c.post("/v1/submissions", content=bomb, params={"allow_partial": "true"})
            assert r.status_code == 202, r.text  # a well-formed archive: only the worker's census can tell
            status = server.wait_state(c, r.json()["id"])
            assert status["state"] == "failed" and status["attempts"] == 1, status
            assert "refused before parsing" in status["validation_report"]["text"], status["validation_report"]
            peak = _usage(c, status["id"])["peak_rss_bytes"]
            assert 0 < peak < 512 * MiB, peak


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_a_job_over_its_memory_limit_fails_with_the_reason_and_the_worker_goes_on(make_server, scoring_data):
    # An address-space limit below what the worker has mapped already: the job's first large
    # allocation fails in the job's own process.
    server = make_server(workers=1, scenarios=scoring_data.scenarios, job_memory_bytes=200 * MiB)
    with server.client(server.key("greedy")) as c:
        for _ in range(2):  # the second job is taken by the same, living worker
            sid = c.post("/v1/submissions", content=scoring_data.full.read_bytes()).json()["id"]
            status = server.wait_state(c, sid)
            assert status["state"] == "failed" and status["attempts"] == 1, status
            assert "WOSAC_JOB_MEMORY_BYTES" in status["error"], status["error"]


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_scoring_process_over_its_cpu_budget_is_stopped_with_the_reason():
    """The limits a worker puts on a job's process, applied to a forked process that spins."""
    from wosac_server.settings import Settings
    from wosac_server.job_limits import limit_this_process, why_child_ended

    settings = Settings(job_cpu_budget_s=1, job_memory_bytes=0)
    parent = os.getpid()
    child = os.fork()
    if child == 0:
        limit_this_process(settings, parent)
        while True:
            pass
    started = time.monotonic()
    _, status, usage = os.wait4(child, 0)
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGXCPU
    # The kernel enforces RLIMIT_CPU on its tick-sampled CPU clock, while wait4 reports the scheduler's
    # exact run time: on a busy host a niced process is charged whole ticks it shared. One was seen
    # stopped after 0.899 s of exact run time for a 1 s budget; under a heavier load one took 14 s of
    # wall time to use its second.
    assert 0.5 < usage.ru_utime + usage.ru_stime < 3 and time.monotonic() - started < 60
    assert "CPU-time budget of 1 s (WOSAC_JOB_CPU_BUDGET_S)" in why_child_ended(status, settings, usage.ru_maxrss)


def test_a_scoring_process_whose_worker_died_before_it_was_limited_ends_at_once():
    """A worker killed between its fork and the parent-death signal's set-up sends no signal: its
    job's process must see it has lost its worker and end, not score on beside the job's retry."""
    from wosac_server.settings import Settings
    from wosac_server.job_limits import limit_this_process

    read_end, write_end = os.pipe()
    worker = os.fork()
    if worker == 0:  # the "worker": forks its job's process and dies at once
        worker_pid = os.getpid()
        if os.fork() == 0:
            while os.getppid() == worker_pid:  # until re-parented: the worker is gone
                time.sleep(0.001)
            limit_this_process(Settings(job_nice=0, job_memory_bytes=0), worker_pid)
            os.write(write_end, b"scored on without its worker")
            os._exit(0)
        os._exit(0)
    os.close(write_end)
    os.waitpid(worker, 0)
    with os.fdopen(read_end, "rb") as pipe:
        assert pipe.read() == b""  # every writer closed without writing: the job's process ended


def _closed_within(sock: socket.socket, seconds: float) -> bytes:
    """Everything the server sent before closing the connection; fails if it stays open."""
    sock.settimeout(seconds)
    received = b""
    while True:
        chunk = sock.recv(65536)  # socket.timeout fails the test
        if not chunk:
            return received
        received += chunk


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_slow_clients_are_closed_and_one_client_cannot_hold_every_connection(make_server):
    server = make_server(workers=0, header_timeout_s=1, body_timeout_s=1, max_connections_per_client=4)
    key = server.key("slow-client")
    address = ("127.0.0.1", server.port)
    with socket.create_connection(address) as silent:  # connects, never sends a byte
        assert b"408 Request Timeout" in _closed_within(silent, 5)
    with socket.create_connection(address) as dribbler:  # headers a byte at a time: the deadline still holds
        started = time.monotonic()
        dribbler.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        for byte in b"X-Slow: " + b"a" * 40:
            time.sleep(0.1)
            try:
                dribbler.sendall(bytes([byte]))
            except OSError:
                break
        assert b"408" in _closed_within(dribbler, 5) and time.monotonic() - started < 4.5
    with socket.create_connection(address) as staller:  # a body that stops coming
        staller.sendall(
            f"POST /v1/submissions HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {key}\r\n"
            "Content-Length: 100000\r\n\r\n".encode()
            + as_submission(b"x" * 100)[:10]
        )
        _closed_within(staller, 5)
    with server.client(key) as c:
        assert _listed(c) == []
    time.sleep(0.2)
    assert list((server.data_dir / "uploads").glob("*.body")) == []

    held = []
    for _ in range(4):  # another client (127.0.0.2) takes its whole share
        s = socket.socket()
        s.bind(("127.0.0.2", 0))
        s.connect(address)
        held.append(s)
    try:
        for _ in range(20):
            extra = socket.socket()
            extra.bind(("127.0.0.2", 0))
            extra.connect(address)
            assert b"503 Service Unavailable" in _closed_within(extra, 5)
            extra.close()
        with server.client() as c:  # everyone else is still served
            assert c.get("/healthz").status_code == 200
    finally:
        for s in held:
            s.close()
    refusals = [line for line in server.log.read_text().splitlines() if "refused a connection" in line]
    assert 1 <= len(refusals) <= 5, refusals  # 20 refusals, a few lines: the log is rate-limited


def test_open_uploads_count_against_the_byte_quota_and_are_capped(api_server):
    key = api_server.key("hoarder", max_daily_bytes=1000)
    with api_server.client(key) as c:
        held = c.post("/v1/uploads", headers={"Upload-Length": "800"})
        assert held.status_code == 201
        r = c.post("/v1/submissions", content=as_submission(b"s" * 300))
        assert r.status_code == 413 and "200 bytes left" in r.json()["detail"], r.text
        assert c.post("/v1/uploads", headers={"Upload-Length": "300"}).status_code == 413
        upload = held.json()["upload_id"]
        r = c.patch(f"/v1/uploads/{upload}", content=b"x" * 900, headers={"Upload-Offset": "0"})
        assert r.status_code == 413  # past its declared length
        assert c.delete(f"/v1/uploads/{upload}").status_code == 204
        assert c.post("/v1/submissions", content=as_submission(b"s" * 300)).status_code == 202
    with api_server.client(api_server.key("many-uploads")) as c:
        for _ in range(4):  # WOSAC_MAX_OPEN_UPLOADS defaults to 4
            assert c.post("/v1/uploads").status_code == 201
        r = c.post("/v1/uploads")
        assert r.status_code == 429 and "WOSAC_MAX_OPEN_UPLOADS" in r.json()["detail"]


def test_leaderboard_names_belong_to_the_first_key_per_challenge(api_server):
    alice, bob = api_server.key("alice-team"), api_server.key("bob-team")
    body = as_submission(b"n" * 64)

    def methods(*args):
        return subprocess.run(
            [*WOSAC_SERVER, "methods", *args],
            env=api_server.env,
            capture_output=True,
            text=True,
            timeout=60,
        )

    with api_server.client(alice) as a, api_server.client(bob) as b:
        assert a.post("/v1/submissions", content=body, params={"method": "rocket"}).status_code == 202
        r = b.post("/v1/submissions", content=body, params={"method": "rocket"})
        assert r.status_code == 403 and "belongs to another key" in r.json()["detail"]
        assert b.post("/v1/uploads", params={"method": "rocket"}).status_code == 403
        assert b.post("/v1/submissions", content=body, params={"method": "alice-team"}).status_code == 403
        assert b.post("/v1/submissions", content=body).status_code == 202  # its own name
        sg = {"method": "rocket", "challenge": "scenario_gen"}
        assert b.post("/v1/submissions", content=body, params=sg).status_code == 202  # first there
        assert a.post("/v1/submissions", content=body, params=sg).status_code == 403
        done = methods("assign", "--method", "rocket", "--key", "bob-team")  # the operator's override
        assert done.returncode == 0, done.stderr
        assert b.post("/v1/submissions", content=body, params={"method": "rocket"}).status_code == 202
        assert a.post("/v1/submissions", content=body, params={"method": "rocket"}).status_code == 403
    listing = methods("list").stdout
    assert "sim_agents\trocket\tbob-team" in listing and "scenario_gen\trocket\tbob-team" in listing


def test_look_alike_names_are_the_same_name(api_server):
    """A name is owned by its normal form (case, spacing, compatibility and zero-width characters):
    another key's look-alike is 403 without naming the owner; the owner may use any spelling, stored
    trimmed; non-ASCII forms never pass the name pattern at all (422, for everyone)."""
    owner, other = api_server.key("rocket-owner"), api_server.key("imitator")
    body = as_submission(b"l" * 64)
    with api_server.client(owner) as a, api_server.client(other) as b:
        r = a.post("/v1/submissions", content=body, params={"method": "Team Rocket", "publish": "true"})
        assert r.status_code == 202 and r.json()["method"] == "Team Rocket"
        for look_alike in ("Team  Rocket", "Team Rocket ", "team rocket", "TEAM ROCKET", "Team   rocket  "):
            r = b.post("/v1/submissions", content=body, params={"method": look_alike, "publish": "true"})
            assert r.status_code == 403 and "belongs to another key" in r.json()["detail"], (look_alike, r.text)
            assert "rocket-owner" not in r.text and owner.split("_")[1] not in r.text  # the owner stays unnamed
            assert b.post("/v1/uploads", params={"method": look_alike}).status_code == 403
        for foreign in ("Ｔｅａｍ Rocket", "Team\u00a0Rocket", "Team\u200bRocket", "Team Rocket\u200b"):
            for c in (a, b):
                r = c.post("/v1/submissions", content=body, params={"method": foreign})
                assert r.status_code == 422, (foreign, r.text)
        assert b.post("/v1/submissions", content=body, params={"method": "ROCKET-OWNER"}).status_code == 403
        r = a.post("/v1/submissions", content=body, params={"method": "team  ROCKET "})  # the owner's own
        assert r.status_code == 202 and r.json()["method"] == "team ROCKET", r.text
        r = b.post("/v1/submissions", content=body, params={"method": "Team Rocketeer "})  # another name
        assert r.status_code == 202 and r.json()["method"] == "Team Rocketeer", r.text
        methods = {s["method"] for s in _listed(b)}
        assert methods == {"Team Rocketeer"}, methods
    with pytest.raises(ValueError, match="already exists"):
        api_server.key("Rocket-Owner ")
    claims = api_server.store.fetchall("SELECT method, key_id FROM method_names WHERE name_key = 'team rocket'")
    assert claims == [{"method": "Team Rocket", "key_id": owner.split("_")[1]}]


def _race(calls) -> list:
    """Run the calls at the same moment on threads; their results in order."""
    barrier, results = threading.Barrier(len(calls)), [None] * len(calls)

    def run(i, call):
        barrier.wait()
        results[i] = call()

    threads = [threading.Thread(target=run, args=(i, call)) for i, call in enumerate(calls)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return results


def test_upload_requests_racing_each_other_never_corrupt_or_fail(api_server):
    key = api_server.key("racer")
    with api_server.client(key) as c:
        upload = c.post("/v1/uploads").json()["upload_id"]
        assert c.patch(f"/v1/uploads/{upload}", content=b"part", headers={"Upload-Offset": "0"}).status_code == 204
        # What a request in flight leaves in the store: the others are turned away, nothing changes.
        api_server.store.execute("UPDATE uploads SET state = 'completing' WHERE id = ?", (upload,))
        for r in (
            c.patch(f"/v1/uploads/{upload}", content=b"more", headers={"Upload-Offset": "4"}),
            c.delete(f"/v1/uploads/{upload}"),
            c.post(f"/v1/uploads/{upload}/complete"),
        ):
            assert r.status_code == 409 and "complete of this upload is in progress" in r.json()["detail"]
        api_server.store.execute("UPDATE uploads SET state = 'open' WHERE id = ?", (upload,))
        assert c.delete(f"/v1/uploads/{upload}").status_code == 204

    for round_ in range(6):
        body = tar_bytes({"s.binproto": as_submission(os.urandom(300_000))})
        with api_server.client(key) as c:
            upload = c.post("/v1/uploads").json()["upload_id"]
            assert c.patch(f"/v1/uploads/{upload}", content=body, headers={"Upload-Offset": "0"}).status_code == 204
            clients = [api_server.client(key) for _ in range(7)]
            try:
                rs = _race(
                    [lambda k=k: k.post(f"/v1/uploads/{upload}/complete") for k in clients[:3]]
                    + [
                        lambda k=k: k.patch(
                            f"/v1/uploads/{upload}", content=b"tail", headers={"Upload-Offset": str(len(body))}
                        )
                        for k in clients[3:5]
                    ]
                    + [lambda k=k: k.delete(f"/v1/uploads/{upload}") for k in clients[5:]]
                )
            finally:
                for k in clients:
                    k.close()
            codes = [r.status_code for r in rs]
            assert all(code < 500 for code in codes), (round_, codes)
            accepted = {r.json()["id"] for r in rs[:3] if r.status_code == 202}
            assert len(accepted) <= 1, codes
            row = c.get(f"/v1/uploads/{upload}")
            if accepted:  # completed: DELETE lost, the stored submission is exactly the body
                sid = accepted.pop()
                assert row.json()["submission_id"] == sid
                assert (api_server.data_dir / "submissions" / f"{sid}.tar.gz").read_bytes() == body
                assert not any(r.status_code == 204 for r in rs[5:]), codes
            else:  # deleted (or a PATCH got in first and the upload is still open): never half of both
                assert row.status_code in (404, 200), codes
                if row.status_code == 200:
                    assert row.json()["submission_id"] is None
                    # Still open: the key may hold only a few open uploads, so close it as a client would.
                    assert c.delete(f"/v1/uploads/{upload}").status_code == 204

    with api_server.client(key) as c:  # a refused archive completed twice at once: one 422, no 500
        upload = c.post("/v1/uploads").json()["upload_id"]
        bad = tar_bytes({"../evil.binproto": b"x"})
        assert c.patch(f"/v1/uploads/{upload}", content=bad, headers={"Upload-Offset": "0"}).status_code == 204
        clients = [api_server.client(key) for _ in range(2)]
        try:
            codes = sorted(
                r.status_code for r in _race([lambda k=k: k.post(f"/v1/uploads/{upload}/complete") for k in clients])
            )
        finally:
            for k in clients:
                k.close()
        assert codes.count(422) == 1 and set(codes) <= {404, 409, 422}, codes


def _simultaneous_uploads(server, key: str, count: int, **kwargs) -> list[int]:
    """`count` POST /v1/submissions from one key released together, each on its own connection; the codes."""
    clients = [server.client(key) for _ in range(count)]
    try:
        return [r.status_code for r in _race([lambda c=c: c.post("/v1/submissions", **kwargs) for c in clients])]
    finally:
        for c in clients:
            c.close()


def _finish(server, key: str, keep: int) -> None:
    """What a worker does when jobs end: all but `keep` of the key's unfinished jobs fail (no worker runs)."""
    with server.client(key) as c:
        queued = [s["id"] for s in _listed(c) if s["state"] == "queued"]
    for sid in queued[keep:]:
        server.store.execute("UPDATE submissions SET state = 'failed', error = 'test' WHERE id = ?", (sid,))


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_simultaneous_uploads_from_one_key_take_exactly_the_free_slots(api_server):
    """K uploads at once on a key with N free job slots: exactly N accepted, every round; the refused
    ones hold nothing (the slots freed afterwards take exactly that many uploads again)."""
    key = api_server.key("stampede", max_concurrent=3)
    body = as_submission(b"s" * 2000)
    with api_server.client(key) as c:
        for round_, free in enumerate([3, 2, 1, 3, 1, 2, 3, 2]):
            _finish(api_server, key, keep=3 - free)
            codes = _simultaneous_uploads(api_server, key, 12, content=body)
            assert sorted(codes) == [202] * free + [429] * (12 - free), (round_, free, codes)
            assert sum(s["state"] == "queued" for s in _listed(c)) == 3
        _finish(api_server, key, keep=2)
        assert c.post("/v1/submissions", content=body).status_code == 202  # the one free slot
        assert c.post("/v1/submissions", content=body).status_code == 429

    # The day's submissions and bytes likewise: exactly what is left of them, never less.
    codes = _simultaneous_uploads(api_server, api_server.key("daily-stampede", max_daily=2), 12, content=body)
    assert sorted(codes) == [202] * 2 + [429] * 10, codes
    bytes_key = api_server.key("bytes-stampede", max_daily_bytes=3 * len(body) + 100)
    codes = _simultaneous_uploads(api_server, bytes_key, 12, content=body)
    assert sorted(codes) == [202] * 3 + [413] * 9, codes

    # Completes of resumable uploads at once: as many as there are free slots; the others keep their bytes.
    key = api_server.key("complete-stampede", max_concurrent=2)
    with api_server.client(key) as c:
        uploads = [c.post("/v1/uploads").json()["upload_id"] for _ in range(4)]
        for upload in uploads:
            assert c.patch(f"/v1/uploads/{upload}", content=body, headers={"Upload-Offset": "0"}).status_code == 204
        clients = [api_server.client(key) for _ in uploads]
        try:
            rs = _race([lambda k=k, u=u: k.post(f"/v1/uploads/{u}/complete") for k, u in zip(clients, uploads)])
        finally:
            for k in clients:
                k.close()
        assert sorted(r.status_code for r in rs) == [202, 202, 429, 429], [r.text for r in rs]
        _finish(api_server, key, keep=0)
        for upload, r in zip(uploads, rs):
            if r.status_code == 429:  # still open with its bytes: completes once a slot is free
                assert c.post(f"/v1/uploads/{upload}/complete").status_code == 202


def test_a_result_file_missing_on_disk_is_410_not_a_server_error(api_server):
    with api_server.client(api_server.key("lost-result")) as c:
        sid = c.post("/v1/submissions", content=as_submission(b"r" * 64)).json()["id"]
        api_server.store.execute("UPDATE submissions SET state = 'done' WHERE id = ?", (sid,))
        for fmt in ("json", "csv"):
            r = c.get(f"/v1/submissions/{sid}/results", params={"format": fmt})
            assert r.status_code == 410 and "missing on the server" in r.json()["detail"]


def test_every_compression_is_checked_and_foreign_bodies_are_415(api_server):
    shard = as_submission(b"c" * 2000)
    with api_server.client(api_server.key("compressor")) as c:
        for kind in ("bz2", "xz"):
            r = c.post("/v1/submissions", content=tar_stream([("../evil.binproto", 10, b"x")], kind))
            assert r.status_code == 422 and "'..' component" in r.json()["detail"], (kind, r.text)
            r = c.post("/v1/submissions", content=tar_stream([("s.binproto", len(shard), shard)], kind))
            assert r.status_code == 202, r.text
            stored = api_server.data_dir / "submissions" / f"{r.json()['id']}.tar.{kind}"
            assert stored.exists()
        import gzip

        r = c.post("/v1/submissions", content=gzip.compress(shard))
        assert r.status_code == 202 and (api_server.data_dir / "submissions" / f"{r.json()['id']}.binproto.gz").exists()
        for body, kind in (
            (json.dumps({"scenario_rollouts": []}).encode(), "JSON"),
            (b"\x89PNG\r\n\x1a\n" + b"\0" * 64, "a PNG image"),
        ):
            r = c.post("/v1/submissions", content=body)
            assert r.status_code == 415 and kind in r.json()["detail"], r.text
        r = c.post("/v1/submissions", content=tar_bytes({"s.binproto": b'{"json": true}'}))
        assert r.status_code == 415 and "member 's.binproto'" in r.json()["detail"]
        assert str(api_server.data_dir) not in r.json()["detail"]
        # A form upload (curl -F) is told to send the raw body, before the body is read.
        r = c.post("/v1/submissions", files={"file": ("sub.tar.gz", tar_bytes({"s.binproto": shard}))})
        assert r.status_code == 415 and "--data-binary" in r.json()["detail"], r.text
        # curl --data-binary without -H labels the raw file application/x-www-form-urlencoded: accepted.
        r = c.post(
            "/v1/submissions",
            content=tar_bytes({"s.binproto": shard}),
            headers={"Content-Type": "application/x-www-form-urlencoded"},
        )
        assert r.status_code == 202, r.text


@pytest.mark.parametrize("limit", [3])
def test_failed_authentication_is_throttled_per_address(make_server, limit):
    server = make_server(workers=0, auth_failures_per_minute=limit)
    key = server.key("honest")
    guess = key[:-6] + "guess0"
    with server.client(guess) as c:
        for _ in range(limit):
            assert c.get("/v1/submissions").status_code == 401
        r = c.get("/v1/submissions")
        assert r.status_code == 429 and 0 < int(r.headers["retry-after"]) <= 61
    with server.client(key) as c:  # the guessing address is shut out, whatever the key
        assert c.get("/v1/submissions").status_code == 429
        assert c.get("/v1/leaderboard").status_code == 200  # public pages stay open
    with server.client(key, source="127.0.0.2") as c:  # other clients are not
        assert c.get("/v1/submissions").status_code == 200


@pytest.mark.parametrize("limit", [3])
@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_forwarded_for_is_believed_only_from_trusted_proxies(make_server, limit):
    """uvicorn alone believes X-Forwarded-For from 127.0.0.1: rotating it would dodge the per-address
    throttle. Without WOSAC_TRUSTED_PROXIES the peer address counts."""
    server = make_server(workers=0, auth_failures_per_minute=limit)
    guess = server.key("honest")[:-6] + "guess0"
    with server.client(guess) as c:
        for n in range(limit):
            assert c.get("/v1/submissions", headers={"X-Forwarded-For": f"203.0.113.{n}"}).status_code == 401
        r = c.get("/v1/submissions", headers={"X-Forwarded-For": "203.0.113.200"})
        assert r.status_code == 429, r.text
    trusting = make_server(workers=0, auth_failures_per_minute=limit, trusted_proxies="127.0.0.1")
    guess = trusting.key("behind-proxy")[:-6] + "guess0"
    with trusting.client(guess) as c:  # behind a trusted proxy, each forwarded address is its own client
        for n in range(limit + 2):
            assert c.get("/v1/submissions", headers={"X-Forwarded-For": f"203.0.113.{n}"}).status_code == 401
