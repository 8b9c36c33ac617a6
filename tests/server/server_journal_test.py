"""A job whose worker dies resumes from its journal, not from zero: the real service (one worker), a
16-scenario submission, the worker killed with SIGKILL mid-job (its scoring process dies with it); the
retry skips the journaled scenarios and gives the result of an uninterrupted run. Meanwhile the data
dir never holds more than 1.1 times the upload (no decompressed copy of the archive)."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from support.server_harness import canonical, resumed_and_scored, wait_gone

# The service end to end (a job's worker killed mid-job and resumed): the CI tier's (`pytest --ci`).
pytestmark = pytest.mark.ci

N = 16


def journal_rows(path: Path) -> int:
    try:
        return max(0, path.read_bytes().count(b"\n") - 1)  # the header line is not a row
    except FileNotFoundError:
        return 0


def stored_bytes(data_dir: Path) -> int:
    """What the service's files take in the data dir, its database and disk reserve aside."""
    total = 0
    for path in data_dir.rglob("*"):
        if path.name.startswith("wosac.sqlite3") or path.name == "disk-reserve":
            continue
        try:
            total += path.stat().st_size if path.is_file() else 0
        except FileNotFoundError:  # gone while walked
            pass
    return total


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_job_whose_worker_is_killed_resumes_from_its_journal(make_server, replicated_job):
    scenarios, submission, expected = replicated_job
    server = make_server(workers=1, scenarios=[scenarios], scene_pictures=0)
    peak, spooled, watching = [0], [False], threading.Event()

    def watch_disk():  # the data dir's peak use while the job is received and scored
        while not watching.is_set():
            peak[0] = max(peak[0], stored_bytes(server.data_dir))
            spooled[0] = spooled[0] or (server.data_dir / "spool").exists()
            time.sleep(0.01)

    watcher = threading.Thread(target=watch_disk, daemon=True)
    watcher.start()
    with server.client(server.key("journal")) as c:
        sid = c.post("/v1/submissions", content=submission.read_bytes()).json()["id"]
        journal = server.data_dir / "results" / f"{sid}.journal"
        deadline = time.monotonic() + 60
        while journal_rows(journal) < 4 and time.monotonic() < deadline:
            time.sleep(0.005)
        row = server.store.fetchone("SELECT lease_owner FROM submissions WHERE id = ?", (sid,))
        os.kill(int(row["lease_owner"].split(":")[1]), signal.SIGKILL)  # its job's process dies with it
        at_kill = journal_rows(journal)
        assert 4 <= at_kill < N, at_kill
        status = server.wait_state(c, sid, timeout=90)
        assert status["state"] == "done" and status["attempts"] == 2, status
        assert canonical(c.get(f"/v1/submissions/{sid}/results").json()) == expected
    watching.set()
    watcher.join()
    # The second attempt started from the journal: it scored only what the first had not.
    resumed, scored = resumed_and_scored(server.log, sid)
    assert resumed >= at_kill - 1 and resumed + scored == N, (resumed, scored, at_kill)
    assert wait_gone(journal)  # removed by the worker once the job's process ended
    size = submission.stat().st_size
    assert size <= peak[0] <= 1.1 * size and not spooled[0], (peak[0], size)
