"""Disk space, end to end: the real server on 127.0.0.1 with its data dir on a 64 MiB filesystem of its
own (a tmpfs; the tests skip, saying why, where mounting one is not permitted), filled by another
file as another process would. Past the floor new uploads and chunks get 507 with Retry-After, counting
what open uploads and queued jobs still need; on a disk that filled anyway no upload is left `writing`,
DELETE frees space, and a worker waits for space (logging once) and then scores the job."""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from support.server_harness import canonical, resumed_and_scored, wait_gone, wait_logged

# The service end to end (disks filled under a running service): the CI tier's (`pytest --ci`).
pytestmark = pytest.mark.ci

MiB = 2**20
DISK_MIB = 64


@pytest.fixture
def small_disk(tmp_path):
    """A 64 MiB tmpfs for the data dir (requested before make_server, so it is unmounted after the server
    stopped)."""
    mount = tmp_path / "data"
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("these tests mount a 64 MiB tmpfs for the data dir, which needs root")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={DISK_MIB}m", "tmpfs", str(mount)], capture_output=True, text=True
    )
    if done.returncode != 0:
        pytest.skip(f"mounting a tmpfs for the data dir is not permitted here: {done.stderr.strip()}")
    yield mount
    subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def fill(path: Path, leave: int = 0) -> None:
    """Grow `path` (a file outside the service's folders) until its disk has at most `leave` bytes free."""
    # Unbuffered: a buffered file keeps the part of a write the full disk refused and raises ENOSPC again
    # when the `with` closes it (seen on CPython 3.10), outside the `try`.
    with open(path, "ab", buffering=0) as f:
        try:
            while (room := shutil.disk_usage(path.parent).free - leave) > 0:
                f.write(bytes(min(room, MiB)))
        except OSError as exc:
            if exc.errno != errno.ENOSPC:
                raise


def health(client) -> dict:
    answer = client.get("/healthz")
    assert answer.status_code == 200, answer.text
    return answer.json()


def raw_request(server, head: str, body_chunks=()) -> tuple[int, dict, dict]:
    """(status, headers, JSON body) of a request sent on a raw socket: the body from a thread, so that an
    answer given before the body was read (and the connection closed) is still seen."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=30) as s:
        s.sendall(head.encode())

        def send_body():
            try:
                for chunk in body_chunks:
                    s.sendall(chunk)
            except OSError:
                pass  # the server answered and closed without reading the rest: expected

        sender = threading.Thread(target=send_body, daemon=True)
        sender.start()
        data = b""
        while b"\r\n\r\n" not in data:
            data += s.recv(65536) or b"\r\n\r\n"
        head_part, _, rest = data.partition(b"\r\n\r\n")
        lines = head_part.decode().split("\r\n")
        headers = {k.strip().lower(): v.strip() for k, v in (line.split(":", 1) for line in lines[1:])}
        length = int(headers.get("content-length", "0"))
        while len(rest) < length:
            more = s.recv(65536)
            if not more:
                break
            rest += more
        return int(lines[0].split()[1]), headers, json.loads(rest[:length] or b"null")


def assert_507(status: int, headers, body) -> None:
    assert status == 507, (status, body)
    assert int(headers["retry-after"]) > 0
    detail = body["detail"]
    assert "disk" in detail and "\n" not in detail and detail.count(". ") == 0, detail


def upload_states(server) -> dict[str, str]:
    return {r["id"]: r["state"] for r in server.store.fetchall("SELECT id, state FROM uploads")}


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_uploads_past_the_floor_get_507_counting_what_open_uploads_and_jobs_still_need(small_disk, make_server):
    server = make_server(data_dir=small_disk, workers=0, min_free_fraction=0.10, disk_reserve_bytes=MiB)
    key = server.key("floor")
    with server.client(key) as c:
        state = health(c)
        assert state["status"] == "ok" and state["disk"]["refusing_uploads"] is False
        assert state["disk"]["floor_bytes"] == int(0.10 * DISK_MIB * MiB) and state["disk"]["reserved_bytes"] == 0
        assert (small_disk / "disk-reserve").stat().st_size == MiB

        # 40 MiB declared: promised at once, with what its job will write.
        big = c.post("/v1/uploads", headers={"Upload-Length": str(40 * MiB)})
        assert big.status_code == 201, big.text
        big_id = big.json()["upload_id"]
        reserved = health(c)["disk"]["reserved_bytes"]
        assert 41 * MiB <= reserved <= 44 * MiB, reserved
        # 16 MiB more would take the disk past its 10 % floor: refused, however it is sent.
        r = c.post("/v1/uploads", headers={"Upload-Length": str(16 * MiB)})
        assert_507(r.status_code, r.headers, r.json())
        assert_507(
            *raw_request(
                server,
                f"POST /v1/submissions HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {key}"
                f"\r\nContent-Length: {16 * MiB}\r\n\r\n",
            )
        )
        # The promised upload's own chunks go on.
        r = c.patch(f"/v1/uploads/{big_id}", content=os.urandom(MiB), headers={"Upload-Offset": "0"})
        assert r.status_code == 204, r.text
        assert health(c)["disk"]["reserved_bytes"] == reserved - MiB
        # DELETE frees its bytes and its promise.
        assert c.delete(f"/v1/uploads/{big_id}").status_code == 204
        assert health(c)["disk"]["reserved_bytes"] == 0
        small = c.post("/v1/uploads", headers={"Upload-Length": str(16 * MiB)})
        assert small.status_code == 201, small.text

        # Another process takes the disk past the floor: degraded, and every new upload or chunk waits.
        filler = small_disk / "other-process.bin"  # the tmpfs is the data dir: the other file lies in it
        fill(filler, leave=5 * MiB)
        state = health(c)
        assert state["status"] == "degraded" and state["disk"]["refusing_uploads"] is True, state
        for r in (
            c.post("/v1/uploads"),
            c.patch(f"/v1/uploads/{small.json()['upload_id']}", content=b"x" * 1024, headers={"Upload-Offset": "0"}),
        ):
            assert_507(r.status_code, r.headers, r.json())
        assert set(upload_states(server).values()) == {"open"}
        filler.unlink()
        assert health(c)["status"] == "ok"
        assert c.post("/v1/uploads").status_code == 201


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_disk_filled_by_another_process_leaves_nothing_stuck_and_every_job_is_scored(
    small_disk, make_server, scoring_data, direct_single_result, tmp_path
):
    # Floor 0 (only the minimum): here the disk really runs out, as when another process fills it.
    server = make_server(data_dir=small_disk, workers=0, disk_reserve_bytes=MiB, scenarios=scoring_data.scenarios)
    key = server.key("full")
    auth = f"Authorization: Bearer {key}\r\n"
    with server.client(key) as c:
        job = c.post("/v1/submissions", content=scoring_data.single.read_bytes(), params={"allow_partial": "true"})
        assert job.status_code == 202, job.text
        upload = c.post("/v1/uploads").json()["upload_id"]
        assert (
            c.patch(f"/v1/uploads/{upload}", content=os.urandom(MiB), headers={"Upload-Offset": "0"}).status_code == 204
        )

        # A chunk the space check lets in (no Content-Length), which then meets a full disk.
        state = health(c)["disk"]
        fill(small_disk / "other-process-1.bin", leave=state["reserved_bytes"] + state["floor_bytes"] + 2 * MiB)
        chunks = [os.urandom(256 * 1024)] * 32  # 8 MiB, chunked
        head = (
            f"PATCH /v1/uploads/{upload} HTTP/1.1\r\nHost: x\r\n{auth}Upload-Offset: {MiB}\r\n"
            "Transfer-Encoding: chunked\r\n\r\n"
        )
        framed = [b"%x\r\n%s\r\n" % (len(x), x) for x in chunks] + [b"0\r\n\r\n"]
        assert_507(*raw_request(server, head, framed))
        # Not left `writing`: the offset is the committed one, the bytes past it are gone, it takes requests.
        assert upload_states(server)[upload] == "open"
        assert c.get(f"/v1/uploads/{upload}").json()["offset"] == MiB
        assert (small_disk / "uploads" / f"{upload}.part").stat().st_size == MiB

        # Now wholly full: everything that needs space answers 507, and says when to retry.
        fill(small_disk / "other-process-2.bin")
        state = health(c)
        assert state["status"] == "degraded" and state["disk"]["free_bytes"] < MiB, state
        assert_507(
            *raw_request(server, f"POST /v1/submissions HTTP/1.1\r\nHost: x\r\n{auth}Content-Length: {MiB}\r\n\r\n")
        )
        r = c.post("/v1/uploads")
        assert_507(r.status_code, r.headers, r.json())
        r = c.patch(f"/v1/uploads/{upload}", content=b"x" * 1024, headers={"Upload-Offset": str(MiB)})
        assert_507(r.status_code, r.headers, r.json())
        assert upload_states(server) == {upload: "open"}
        # DELETE frees the space even so.
        free = shutil.disk_usage(small_disk).free
        assert c.delete(f"/v1/uploads/{upload}").status_code == 204
        assert not (small_disk / "uploads" / f"{upload}.part").exists()
        assert shutil.disk_usage(small_disk).free >= free + MiB
        assert c.get(f"/v1/uploads/{upload}").status_code == 404

        # A worker (`wosac-server worker`, as on another host) meets the full disk: it waits, logging once.
        fill(small_disk / "other-process-3.bin")
        log = tmp_path / "worker.log"
        with open(log, "wb") as out:
            worker = subprocess.Popen(
                [sys.executable, "-m", "wosac_server", "worker"],
                env=server.env,
                stdout=out,
                stderr=subprocess.STDOUT,
                cwd=tmp_path,
            )
        try:
            time.sleep(4)
            assert worker.poll() is None, log.read_text()
            assert log.read_text().count("waiting for space") == 1, log.read_text()
            assert c.get(f"/v1/submissions/{job.json()['id']}").json()["state"] != "failed"

            for filler in small_disk.glob("other-process-*.bin"):
                filler.unlink()
            status = server.wait_state(c, job.json()["id"], timeout=60)
            assert status["state"] == "done" and status["attempts"] == 1, status
            assert canonical(c.get(f"/v1/submissions/{status['id']}/results").json()) == canonical(direct_single_result)
            # Logged once the worker's next write succeeds, which may be after the job's end is recorded.
            assert "space is back" in wait_logged(log, "space is back")
        finally:
            worker.send_signal(signal.SIGTERM)
            worker.wait(20)
        assert list((small_disk / "results").glob("*.journal")) == []
        deadline = time.monotonic() + 10  # the API's maintenance round makes the reserve file again
        while not (small_disk / "disk-reserve").exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert (small_disk / "disk-reserve").stat().st_size == MiB
        assert health(c)["status"] == "ok"


def journal_rows(path: Path) -> int:
    try:
        return max(0, path.read_bytes().count(b"\n") - 1)  # the header line is not a row
    except FileNotFoundError:
        return 0


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_worker_whose_disk_fills_mid_job_waits_and_loses_no_scored_scenario(small_disk, make_server, replicated_job):
    scenarios, submission, expected = replicated_job
    n = 16
    server = make_server(
        data_dir=small_disk, workers=1, disk_reserve_bytes=MiB, scenarios=[scenarios], scene_pictures=0
    )
    with server.client(server.key("midjob")) as c:
        sid = c.post("/v1/submissions", content=submission.read_bytes()).json()["id"]
        journal = small_disk / "results" / f"{sid}.journal"
        deadline = time.monotonic() + 60
        while journal_rows(journal) < 3 and time.monotonic() < deadline:
            time.sleep(0.005)
        filler = small_disk / "other-process.bin"
        fill(filler)
        at_fill = journal_rows(journal)
        assert 3 <= at_fill < n, at_fill
        # The next rows may still fit the filesystem's last allocated page: the worker meets the full disk
        # at the first write that needs a new block, later on a slower interpreter.
        deadline = time.monotonic() + 60
        while "waiting for space" not in server.log.read_text() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.5)  # a while on the full disk: the job waits, it does not fail
        assert c.get(f"/v1/submissions/{sid}").json()["state"] == "scoring"
        assert server.log.read_text().count("waiting for space") == 1, server.log.read_text()
        filler.unlink()
        status = server.wait_state(c, sid, timeout=60)
        assert status["state"] == "done" and status["attempts"] == 1, status
        assert canonical(c.get(f"/v1/submissions/{sid}/results").json()) == expected
    # Logged when the retried scoring returns, which is after it recorded the job done (until_written).
    assert "space is back" in wait_logged(server.log, "space is back")
    # Scoring went on from the journal: the rows written before the disk filled were not scored again.
    resumed, scored = resumed_and_scored(server.log, sid)
    assert resumed >= at_fill - 1 and resumed + scored == n, (resumed, scored, at_fill)
    assert wait_gone(journal)  # removed by the worker once its job's process ended


@pytest.mark.parametrize("reserve", [MiB, 0], ids=["with-reserve", "without-reserve"])
def test_an_upload_state_a_full_database_could_not_record_is_recorded_once_it_can(small_disk, make_server, reserve):
    """A PATCH whose first byte meets a full disk, with SQLite on that disk and its WAL emptied: the state
    write back to `open` fails too. With a reserve file it is freed and the write goes through at once;
    without one the upload stays `writing` only until the database can write again (the next request)."""
    import sqlite3

    server = make_server(data_dir=small_disk, workers=0, disk_reserve_bytes=reserve)
    key = server.key("wal")
    with server.client(key) as c:
        upload = c.post("/v1/uploads").json()["upload_id"]
        assert c.patch(f"/v1/uploads/{upload}", content=b"a" * 65536, headers={"Upload-Offset": "0"}).status_code == 204
        with socket.create_connection(("127.0.0.1", server.port), timeout=30) as s:
            s.sendall(
                f"PATCH /v1/uploads/{upload} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {key}\r\n"
                f"Upload-Offset: 65536\r\nContent-Length: {MiB}\r\n\r\n".encode()
            )
            deadline = time.monotonic() + 10
            while upload_states(server)[upload] != "writing" and time.monotonic() < deadline:
                time.sleep(0.01)
            # Every write of the database now needs new blocks: an emptied WAL, then a full disk.
            with sqlite3.connect(small_disk / "wosac.sqlite3") as db:
                assert db.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()[0] == 0
            filler = small_disk / "other-process.bin"
            fill(filler)
            s.sendall(b"b" * MiB)
            answer = s.recv(65536).decode()
        assert answer.startswith("HTTP/1.1 507"), answer
        if reserve:
            assert upload_states(server)[upload] == "open"
            assert not (small_disk / "disk-reserve").exists()
        else:
            assert upload_states(server)[upload] == "writing"
            assert c.get(f"/v1/uploads/{upload}").json()["offset"] == 65536
        filler.unlink()
        assert c.get(f"/v1/uploads/{upload}").json()["offset"] == 65536  # the next request records it
        assert upload_states(server)[upload] == "open"
        r = c.patch(f"/v1/uploads/{upload}", content=b"b" * 1024, headers={"Upload-Offset": "65536"})
        assert r.status_code == 204, r.text
