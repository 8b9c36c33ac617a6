"""The API against a real server on loopback: uploads, auth, quotas, resumable
uploads, bad requests. Its server runs no workers, so accepted jobs stay queued
and every answer here depends on the API alone."""

from __future__ import annotations

import hashlib
import os
import socket
import subprocess
import time
from pathlib import Path

import pytest

from wosac_eval.parse.wire import varint

from support.runs import WOSAC_SERVER
from support.server_harness import GOLDEN_PAIR, as_submission, files_under, tar_bytes


def submission_bytes() -> bytes:
    """A real submission when ../shared is there; otherwise a stand-in the API treats alike
    (it passes the upload check; nothing is scored here: no worker runs)."""
    if GOLDEN_PAIR[0].exists():
        return GOLDEN_PAIR[0].read_bytes()
    return as_submission(hashlib.sha256(b"wosac").digest() * 4096)


def outside_data_dir(server) -> set:
    """Every file under the test's tmp root that is not in the data dir or a server log."""
    root = server.data_dir.parent
    return {p for p in files_under(root) if server.data_dir not in p.parents and not p.name.startswith("server-")}


def test_health_and_openapi_schema(api_server):
    with api_server.client() as c:
        health = c.get("/healthz").json()
        disk = health.pop("disk")
        assert health == {
            "status": "ok",
            "database": "ok",
            "scenario_shards": len(api_server.env["WOSAC_SCENARIOS"].split(",")),
        }
        assert disk["free_bytes"] > disk["floor_bytes"] > 0 and disk["refusing_uploads"] is False
        paths = c.get("/openapi.json").json()["paths"]
    for path in (
        "/v1/submissions",
        "/v1/submissions/{submission_id}",
        "/v1/submissions/{submission_id}/results",
        "/v1/leaderboard",
        "/v1/uploads",
        "/v1/uploads/{upload_id}",
        "/v1/uploads/{upload_id}/complete",
    ):
        assert path in paths


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="reads the server's memory map in /proc")
def test_the_api_process_starts_without_the_scoring_stack(api_server):
    """`serve` loads what answers requests (the upload check's compiled walks included); the scoring
    modules (the features' k-d trees, the pictures' plotting) load in its workers, psycopg only for a
    PostgreSQL store: a second less of every start and restart. Read from the running server's memory map
    (the compiled extension modules it has loaded)."""
    loaded = Path(f"/proc/{api_server.proc.pid}/maps").read_text()
    assert "numba" in loaded  # what the map shows: the extension modules of the packages imported
    for package in ("scipy/spatial", "matplotlib", "psycopg_binary"):
        assert package not in loaded, package


def test_requests_without_a_valid_key_are_401(api_server):
    key = api_server.key("auth-user")
    wrong = key[:-4] + ("AAAA" if not key.endswith("AAAA") else "BBBB")
    with api_server.client() as anon:
        r = anon.post("/v1/submissions", content=b"x")
        assert r.status_code == 401 and r.headers["www-authenticate"].startswith("Bearer")
        assert "missing API key" in r.json()["detail"]
        for bad in (wrong, "not-a-key", "wosac_000000000000_secret"):
            r = anon.get("/v1/submissions", headers={"Authorization": f"Bearer {bad}"})
            assert r.status_code == 401, bad
            assert r.json()["detail"] == "unknown or revoked API key"
        assert anon.get("/v1/submissions", headers={"Authorization": f"Basic {key}"}).status_code == 401
        assert anon.get("/v1/leaderboard").status_code == 200  # public
    with api_server.client(key) as c:
        assert c.get("/v1/submissions").status_code == 200


def test_upload_is_stored_under_a_server_generated_name(api_server):
    key = api_server.key("storer")
    body = submission_bytes()
    before = outside_data_dir(api_server)
    # The server is the session's: other tests' open resumable uploads may lie there already.
    uploads_before = set((api_server.data_dir / "uploads").iterdir())
    with api_server.client(key) as c:
        r = c.post(
            "/v1/submissions",
            content=body,
            params={"config": "2025", "method": "my-method"},
            headers={
                "Content-Disposition": 'attachment; filename="../../escape.binproto"',
                "Content-Type": "application/octet-stream",
            },
        )
        assert r.status_code == 202, r.text
        status = r.json()
        assert r.headers["location"] == f"/v1/submissions/{status['id']}"
        assert status["state"] == "queued" and status["method"] == "my-method"
        assert status["upload_bytes"] == len(body)
        assert c.get(f"/v1/submissions/{status['id']}").json()["state"] == "queued"
        r = c.get(f"/v1/submissions/{status['id']}/results")
        assert r.status_code == 409 and "queued" in r.json()["detail"]
    stored = api_server.data_dir / "submissions" / f"{status['id']}.binproto"
    assert stored.read_bytes() == body
    assert outside_data_dir(api_server) == before
    assert not list(api_server.data_dir.parent.rglob("escape*"))
    assert set((api_server.data_dir / "uploads").iterdir()) == uploads_before  # no temp file left behind


def test_archive_upload_keeps_its_container_suffix(api_server):
    key = api_server.key("archiver")
    body = tar_bytes({"shard-00000-of-00001.binproto": submission_bytes()})
    with api_server.client(key) as c:
        r = c.post("/v1/submissions", content=body)
    assert r.status_code == 202, r.text
    assert (api_server.data_dir / "submissions" / f"{r.json()['id']}.tar.gz").read_bytes() == body


def test_another_users_submission_is_404(api_server):
    alice, bob = api_server.key("alice"), api_server.key("bob")
    with api_server.client(alice) as a, api_server.client(bob) as b:
        sid = a.post("/v1/submissions", content=submission_bytes()).json()["id"]
        assert a.get(f"/v1/submissions/{sid}").status_code == 200
        for path in (f"/v1/submissions/{sid}", f"/v1/submissions/{sid}/results"):
            r = b.get(path)
            assert r.status_code == 404 and sid in r.json()["detail"]
        assert sid not in {s["id"] for s in b.get("/v1/submissions").json()["submissions"]}
        assert sid in {s["id"] for s in a.get("/v1/submissions").json()["submissions"]}
        upload = a.post("/v1/uploads").json()["upload_id"]
        r = b.patch(f"/v1/uploads/{upload}", content=b"abc", headers={"Upload-Offset": "0"})
        assert r.status_code == 404
        assert b.get("/v1/submissions/..%2F..%2Fetc%2Fpasswd").status_code == 404


def test_oversized_bodies_are_413_and_leave_no_file(api_server):
    key = api_server.key("big")
    limit = int(api_server.env["WOSAC_MAX_UPLOAD_BYTES"])
    body = os.urandom(limit + 1)
    with api_server.client(key) as c:
        r = c.post("/v1/submissions", content=body)  # Content-Length up front: refused before reading
        assert r.status_code == 413 and "WOSAC_MAX_UPLOAD_BYTES" in r.json()["detail"]

        def chunks():  # no Content-Length: refused while streaming
            for i in range(0, len(body), 65536):
                yield body[i : i + 65536]

        r = c.post("/v1/submissions", content=chunks())
        assert r.status_code == 413 and str(limit) in r.json()["detail"]
        assert c.get("/v1/submissions").json()["submissions"] == []
    assert list((api_server.data_dir / "uploads").glob("*.body")) == []


@pytest.mark.parametrize(
    "members, reason",
    [
        ({"../../evil.binproto": b"x"}, "'..' component"),
        ({"/tmp/evil.binproto": b"x"}, "absolute path"),
        ({"ok/../../evil.binproto": b"x"}, "'..' component"),
    ],
)
def test_archives_with_traversal_names_are_422(api_server, members, reason):
    key = api_server.key(f"traversal-{abs(hash(tuple(members)))}")
    before = outside_data_dir(api_server)
    with api_server.client(key) as c:
        for gz in (True, False):
            r = c.post("/v1/submissions", content=tar_bytes(members, gz=gz))
            assert r.status_code == 422, r.text
            assert reason in r.json()["detail"] and next(iter(members)) in r.json()["detail"]
        assert c.get("/v1/submissions").json()["submissions"] == []
    assert outside_data_dir(api_server) == before
    assert not list(api_server.data_dir.parent.rglob("evil*"))


def test_links_in_archives_are_422(api_server):
    import io
    import tarfile

    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        link = tarfile.TarInfo("shard.binproto")
        link.type = tarfile.SYMTYPE
        link.linkname = "/etc/passwd"
        tar.addfile(link)
    with api_server.client(api_server.key("linker")) as c:
        r = c.post("/v1/submissions", content=buf.getvalue())
    assert r.status_code == 422 and "link" in r.json()["detail"]


@pytest.mark.parametrize(
    "body, reason",
    [
        (b"\x1f\x8b\x08\x00garbage that is not deflate data" * 20, "broken gzip stream"),
        (tar_bytes({"a.binproto": b"y" * 5000}, gz=False)[:1000], "truncated or corrupt data in member 'a.binproto'"),
        (tar_bytes({"a.binproto": b"y" * 5000})[:-40], "broken gzip stream"),
        (tar_bytes({}, gz=True), "holds no submission shard"),
        (b"", "empty"),
    ],
)
def test_malformed_uploads_are_422(api_server, body, reason):
    with api_server.client(api_server.key(f"malformed-{hashlib.md5(body).hexdigest()}")) as c:
        r = c.post("/v1/submissions", content=body)
        assert r.status_code == 422, r.text
        assert reason in r.json()["detail"]
        assert c.get("/v1/submissions").json()["submissions"] == []


def test_bad_parameters_are_422(api_server):
    with api_server.client(api_server.key("params")) as c:
        r = c.post("/v1/submissions", content=b"x", params={"config": "1999"})
        assert r.status_code == 422 and "unknown config '1999'" in r.json()["detail"]
        assert c.post("/v1/submissions", content=b"x", params={"method": "<script>"}).status_code == 422
        assert c.get("/v1/leaderboard", params={"config": "nope"}).status_code == 422
        assert (
            c.get("/v1/submissions/00000000000000000000000000000000/results", params={"format": "xml"}).status_code
            == 422
        )


def test_quota_on_concurrent_jobs_is_429(api_server):
    key = api_server.key("one-at-a-time", max_concurrent=1)
    with api_server.client(key) as c:
        assert c.post("/v1/submissions", content=as_submission(b"first")).status_code == 202
        r = c.post("/v1/submissions", content=as_submission(b"second"))
        assert r.status_code == 429 and "limit is 1 at a time" in r.json()["detail"]
        assert int(r.headers["retry-after"]) > 0
        assert c.post("/v1/uploads").status_code == 429


def test_quota_on_daily_submissions_is_429(api_server):
    key = api_server.key("twice-a-day", max_daily=2)
    with api_server.client(key) as c:
        assert c.post("/v1/submissions", content=as_submission(b"one")).status_code == 202
        assert c.post("/v1/submissions", content=as_submission(b"two")).status_code == 202
        r = c.post("/v1/submissions", content=as_submission(b"three"))
        assert r.status_code == 429 and "limit is 2 per day" in r.json()["detail"]
        assert 0 < int(r.headers["retry-after"]) <= 24 * 3600 + 1


def test_quota_on_daily_bytes_is_413(api_server):
    key = api_server.key("small-budget", max_daily_bytes=1000)
    with api_server.client(key) as c:
        assert c.post("/v1/submissions", content=as_submission(b"a" * 600)).status_code == 202
        r = c.post("/v1/submissions", content=b"b" * 600)
        assert r.status_code == 413 and "400 bytes left" in r.json()["detail"]
        r = c.post("/v1/submissions", content=iter([b"c" * 300, b"c" * 300]))  # streamed, no length
        assert r.status_code == 413


def _patch(c, upload_id, offset, data):
    return c.patch(
        f"/v1/uploads/{upload_id}",
        content=data,
        headers={"Upload-Offset": str(offset), "Content-Type": "application/offset+octet-stream"},
    )


def _drop_mid_chunk(server, key, upload_id, offset, chunk, sent):
    """Send a PATCH announcing `chunk` but hang up after `sent` bytes of it."""
    head = (
        f"PATCH /v1/uploads/{upload_id} HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {key}\r\n"
        f"Upload-Offset: {offset}\r\nContent-Length: {len(chunk)}\r\n\r\n"
    ).encode()
    with socket.create_connection(("127.0.0.1", server.port)) as s:
        s.sendall(head + chunk[:sent])
        time.sleep(0.3)


def test_resumable_upload_survives_a_dropped_connection(api_server):
    key = api_server.key("resumer")
    body = as_submission(os.urandom(1_000_000))
    with api_server.client(key) as c:
        r = c.post("/v1/uploads", params={"method": "resumed"}, headers={"Upload-Length": str(len(body))})
        assert r.status_code == 201 and r.headers["upload-offset"] == "0"
        upload_id = r.json()["upload_id"]
        assert r.headers["location"] == f"/v1/uploads/{upload_id}"

        r = _patch(c, upload_id, 0, body[:300_000])
        assert r.status_code == 204 and r.headers["upload-offset"] == "300000"
        r = _patch(c, upload_id, 0, body[:10])  # stale offset
        assert r.status_code == 409 and r.headers["upload-offset"] == "300000"

        _drop_mid_chunk(api_server, key, upload_id, 300_000, body[300_000:800_000], sent=123_456)
        deadline = time.monotonic() + 10
        while (offset := int(c.head(f"/v1/uploads/{upload_id}").headers["upload-offset"])) == 300_000:
            assert time.monotonic() < deadline, "the dropped PATCH never settled"
            time.sleep(0.05)
        assert 300_000 < offset <= 423_456  # what arrived before the drop is kept
        assert c.get(f"/v1/uploads/{upload_id}").json() == {
            "upload_id": upload_id,
            "offset": offset,
            "length": len(body),
            "submission_id": None,
        }

        r = c.post(f"/v1/uploads/{upload_id}/complete")
        assert r.status_code == 409 and "PATCH the rest" in r.json()["detail"]
        r = _patch(c, upload_id, offset, body[offset:] + b"extra")  # past Upload-Length
        assert r.status_code == 413
        assert _patch(c, upload_id, offset, body[offset:]).headers["upload-offset"] == str(len(body))

        r = c.post(f"/v1/uploads/{upload_id}/complete")
        assert r.status_code == 202, r.text
        sub = r.json()
        assert sub["method"] == "resumed" and sub["upload_bytes"] == len(body) and sub["state"] == "queued"
        assert c.post(f"/v1/uploads/{upload_id}/complete").json()["id"] == sub["id"]  # idempotent
        assert _patch(c, upload_id, len(body), b"more").status_code == 409
    assert (api_server.data_dir / "submissions" / f"{sub['id']}.binproto").read_bytes() == body
    assert not (api_server.data_dir / "uploads" / f"{upload_id}.part").exists()


def test_resumable_upload_without_declared_length_and_delete(api_server):
    key = api_server.key("chunker")
    body = tar_bytes({"shard.binproto": as_submission(os.urandom(200_000))})
    with api_server.client(key) as c:
        upload_id = c.post("/v1/uploads").json()["upload_id"]
        for start in range(0, len(body), 50_000):
            assert _patch(c, upload_id, start, body[start : start + 50_000]).status_code == 204
        sub = c.post(f"/v1/uploads/{upload_id}/complete").json()
        assert (api_server.data_dir / "submissions" / f"{sub['id']}.tar.gz").read_bytes() == body

        abandoned = c.post("/v1/uploads").json()["upload_id"]
        assert _patch(c, abandoned, 0, b"partial").status_code == 204
        assert c.delete(f"/v1/uploads/{abandoned}").status_code == 204
        assert c.head(f"/v1/uploads/{abandoned}").status_code == 404
    assert not (api_server.data_dir / "uploads" / f"{abandoned}.part").exists()


def test_keys_command_creates_lists_and_revokes(api_server):
    def keys(*args):
        return subprocess.run(
            [*WOSAC_SERVER, "keys", *args],
            env=api_server.env,
            capture_output=True,
            text=True,
            timeout=60,
        )

    created = keys("create", "--name", "carol", "--max-concurrent", "3")
    assert created.returncode == 0, created.stderr
    key = created.stdout.strip()
    assert key.startswith("wosac_")
    with api_server.client(key) as c:
        assert c.get("/v1/submissions").status_code == 200
    assert keys("create", "--name", "carol").returncode == 1
    listing = keys("list").stdout
    secret = key.split("_", 2)[2]  # the whole secret: it may itself hold "_"
    assert "carol" in listing and "concurrent 3" in listing and secret not in listing
    row = api_server.store.fetchone("SELECT key_hash, salt FROM api_keys WHERE name = 'carol'")
    assert secret not in (row["key_hash"], row["salt"])  # only a hash is stored
    assert keys("revoke", "--name", "carol").returncode == 0
    with api_server.client(key) as c:
        assert c.get("/v1/submissions").status_code == 401


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_restart_keeps_accepted_submissions(make_server, tmp_path):
    server = make_server(workers=0)
    key = server.key("restarter")
    bodies = [submission_bytes(), tar_bytes({"s.binproto": as_submission(b"z" * 1000)})]
    with server.client(key) as c:
        ids = [c.post("/v1/submissions", content=b).json()["id"] for b in bodies]
        upload_id = c.post("/v1/uploads").json()["upload_id"]
        assert _patch(c, upload_id, 0, b"half").status_code == 204
    server.stop()
    again = make_server(data_dir=server.data_dir, workers=0)
    with again.client(key) as c:
        listed = c.get("/v1/submissions").json()["submissions"]
        assert sorted(s["id"] for s in listed) == sorted(ids)
        assert {s["state"] for s in listed} == {"queued"}
        assert c.head(f"/v1/uploads/{upload_id}").headers["upload-offset"] == "4"
        assert _patch(c, upload_id, 4, b"-and-rest").headers["upload-offset"] == "13"
    for sid, body in zip(ids, bodies):
        stored = next((server.data_dir / "submissions").glob(f"{sid}.*"))
        assert stored.read_bytes() == body


def test_complete_refused_by_a_quota_keeps_the_uploaded_bytes(api_server):
    key = api_server.key("patient", max_concurrent=1)
    body = as_submission(os.urandom(50_000))
    with api_server.client(key) as c:
        upload_id = c.post("/v1/uploads").json()["upload_id"]
        assert _patch(c, upload_id, 0, body).status_code == 204
        blocker = c.post("/v1/submissions", content=as_submission(b"takes the only slot")).json()["id"]
        r = c.post(f"/v1/uploads/{upload_id}/complete")
        assert r.status_code == 429
        assert c.head(f"/v1/uploads/{upload_id}").headers["upload-offset"] == str(len(body))
        # The blocking job finishes (as a worker would record it); the retry goes through.
        api_server.store.execute("UPDATE submissions SET state = 'done' WHERE id = ?", (blocker,))
        r = c.post(f"/v1/uploads/{upload_id}/complete")
        assert r.status_code == 202, r.text
        assert c.get(f"/v1/uploads/{upload_id}").json()["submission_id"] == r.json()["id"]
    assert (api_server.data_dir / "submissions" / f"{r.json()['id']}.binproto").read_bytes() == body


def _peak_rss_mb(pid: int) -> float:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM in /proc status")


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs Linux /proc to read peak RSS")
@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_a_large_upload_is_streamed_not_held_in_memory(make_server):
    server = make_server(workers=0, max_upload_bytes=400 * 2**20)
    key = server.key("bulk")
    chunk = bytes(range(256)) * 4096  # 1 MiB
    with server.client(key) as c:
        c.get("/v1/submissions")  # warm up every code path before the baseline
        baseline = _peak_rss_mb(server.proc.pid)
        header = b"\x3a" + varint(256 * 2**20 - 5)  # the body is one description field of a submission
        assert len(header) == 5
        first = header + chunk[5:]
        r = c.post("/v1/submissions", content=(first if i == 0 else chunk for i in range(256)))  # 256 MiB, chunked
        assert r.status_code == 202, r.text
        assert r.json()["upload_bytes"] == 256 * 2**20
    growth = _peak_rss_mb(server.proc.pid) - baseline
    assert growth < 48, f"the API process grew by {growth:.0f} MiB while receiving 256 MiB"
    assert (server.data_dir / "submissions" / f"{r.json()['id']}.binproto").stat().st_size == 256 * 2**20
