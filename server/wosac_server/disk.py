"""Disk space of the data dir: what is free, what is promised, and when uploads are refused.

Free space alone is not enough to decide: an open resumable upload has declared bytes still to come,
and a queued job will write its journal and result. Both are *reserved*: counted as if written. A new
upload or chunk is refused (`507` with `Retry-After`) when free space less the reservations less
what it would add falls below the floor (`WOSAC_MIN_FREE_FRACTION` of the disk, at least
`WOSAC_MIN_FREE_BYTES`), so the service never fills its disk by its own hand.

When the disk fills anyway (another process, a shared volume), writes fail with ENOSPC (or EDQUOT,
SQLite's SQLITE_FULL, PostgreSQL's 53100): requests answer `507`, and the small *reserve* file
(`WOSAC_DISK_RESERVE_BYTES`) is deleted so that the database can still record the states that must
not stay behind (an upload back to `open`); it is made again once there is room.
A worker that meets a full disk waits for space (`DiskWait`) instead of crash-looping.
"""

from __future__ import annotations

import dataclasses
import errno
import logging
import os
import shutil
import sqlite3
import time
from collections.abc import Callable

from .db import Store
from .errors import NoSpace
from .settings import Settings

log = logging.getLogger("wosac_server.disk")

RETRY_AFTER_S = 60
# Every request that stores bytes leaves at least this much free, whatever the floor is set to.
MIN_FLOOR_BYTES = 1024**2
# A job's own files: its journal and result rows (~3.4 KB each per scenario today), its pictures, and
# its per-object values: the objects file and, while it scores, their copy in the journal (~1.1 KB an
# object each; a WOMD scene evaluates ~23 objects on average, up to a few hundred; 8 bytes of row index).
JOB_OBJECT_BYTES_PER_SCENARIO = 56 * 1024
JOB_BYTES_PER_SCENARIO = 8 * 1024 + JOB_OBJECT_BYTES_PER_SCENARIO
JOB_BASE_BYTES = 1024**2
# Before validation counts its scenarios: a share of the upload (a scenario's rollouts take 100 KB
# to 1 MB uploaded, its two rows 7 KB).
JOB_UPLOAD_DIVISOR = 16
FULL_DETAIL = "the server's disk is full; retry later (resumable uploads keep what was stored)"


SQLITE_FULL = 13  # SQLite's result code for "database or disk is full" (a stable part of its C API)


def is_disk_full(exc: BaseException) -> bool:
    """An error that means the data dir's disk (or the database's) has no room left."""
    if isinstance(exc, OSError):
        return exc.errno in (errno.ENOSPC, errno.EDQUOT)
    if isinstance(exc, sqlite3.Error):
        # sqlite_errorcode and the sqlite3.SQLITE_FULL constant are Python 3.11's; 3.10 has the message only.
        return getattr(exc, "sqlite_errorcode", None) == SQLITE_FULL or "disk is full" in str(exc)
    return getattr(exc, "sqlstate", None) == "53100"  # psycopg's DiskFull


def full_error_types(dialect: str) -> list[type[Exception]]:
    """The exception classes `is_disk_full` may accept (for the app's exception handler) with a store of
    `dialect` ("sqlite" or "postgresql": psycopg imported only for the latter, a slow import)."""
    types: list[type[Exception]] = [OSError, sqlite3.Error]
    if dialect != "postgresql":
        return types
    import psycopg

    return [*types, psycopg.errors.DiskFull]


def full_answer() -> NoSpace:
    return NoSpace(FULL_DETAIL, retry_after_s=RETRY_AFTER_S)


def job_need_bytes(upload_bytes: int, scenarios: int | None = None) -> int:
    """What a job will write besides its upload (journal, result, pictures): an estimate on the safe side."""
    if scenarios is not None:
        return JOB_BASE_BYTES + scenarios * JOB_BYTES_PER_SCENARIO
    return JOB_BASE_BYTES + upload_bytes // JOB_UPLOAD_DIVISOR


def reserved_in_store(store: Store) -> int:
    """Bytes promised by the database's rows: open uploads' declared bytes still to come and the files of
    the jobs they will become, and the files of queued and running jobs."""
    uploads = store.fetch_aggregate(
        "SELECT COUNT(*) AS n, COALESCE(SUM(declared_length - received_bytes), 0) AS still,"
        " COALESCE(SUM(COALESCE(declared_length, received_bytes)), 0) AS total FROM uploads"
        " WHERE submission_id IS NULL AND state != 'deleting'"
    )
    running = store.fetch_aggregate(
        "SELECT COUNT(*) AS n, COALESCE(SUM(COALESCE(scenarios_total * ?, upload_bytes / ?)), 0) AS need"
        " FROM submissions WHERE state IN ('queued', 'validating', 'scoring')",
        (JOB_BYTES_PER_SCENARIO, JOB_UPLOAD_DIVISOR),
    )
    return (
        max(0, int(uploads["still"]))
        + uploads["n"] * JOB_BASE_BYTES
        + int(uploads["total"]) // JOB_UPLOAD_DIVISOR
        + running["n"] * JOB_BASE_BYTES
        + int(running["need"])
    )


@dataclasses.dataclass(frozen=True)
class DiskState:
    total: int  # the data dir's filesystem
    free: int  # available to this process (shutil.disk_usage)
    reserved: int  # promised to open uploads and jobs, not written yet
    floor: int  # kept free

    def room(self, extra: int = 0) -> int:
        """Bytes that may still be promised after `extra` more (negative: refuse)."""
        return self.free - self.reserved - extra - self.floor

    @property
    def refusing(self) -> bool:
        return self.room() < 0

    def refusal(self) -> NoSpace:
        return NoSpace(
            f"the server's disk is too full to take this upload now ({self.free} bytes free, "
            f"{self.reserved} promised to uploads and jobs in progress, {self.floor} kept free); "
            f"retry in {RETRY_AFTER_S} s",
            retry_after_s=RETRY_AFTER_S,
        )


def floor_bytes(settings: Settings, total: int) -> int:
    return max(int(settings.min_free_fraction * total), settings.min_free_bytes, MIN_FLOOR_BYTES)


def measure(settings: Settings, store: Store, in_flight: int = 0) -> DiskState:
    """The disk of the data dir now; `in_flight`: bytes promised by requests of this process."""
    usage = shutil.disk_usage(settings.data_dir)
    return DiskState(usage.total, usage.free, reserved_in_store(store) + in_flight, floor_bytes(settings, usage.total))


# -- the reserve file --------------------------------------------------------------------------
def release_reserve(settings: Settings) -> bool:
    """Delete the reserve file (the disk is full): True when there was one to free."""
    try:
        settings.disk_reserve_path.unlink()
    except FileNotFoundError:
        return False
    log.warning("the data dir's disk is full: freed the %d bytes of its reserve file", settings.disk_reserve_bytes)
    return True


def restore_reserve(settings: Settings, state: DiskState) -> None:
    """Make the reserve file when it is missing and taking its space refuses no upload."""
    path, size = settings.disk_reserve_path, settings.disk_reserve_bytes
    if size == 0:
        path.unlink(missing_ok=True)
        return
    if path.exists() or state.room(size) < 0:
        return
    temp = path.with_name(path.name + ".tmp")
    try:
        with open(temp, "wb") as f:
            try:
                os.posix_fallocate(f.fileno(), 0, size)  # blocks really taken: a sparse file would free nothing
            except OSError as exc:
                if is_disk_full(exc):
                    raise
                for _ in range(0, size, MIN_FLOOR_BYTES):  # a filesystem without fallocate: write it
                    f.write(bytes(min(MIN_FLOOR_BYTES, size - f.tell())))
            f.flush()
            os.fsync(f.fileno())
        os.replace(temp, path)
    except OSError as exc:
        temp.unlink(missing_ok=True)
        log.warning("could not make the disk reserve file (%s); trying again later", exc)


def release_reserve_if_low(settings: Settings) -> None:
    """At start-up: a disk with less free than the reserve gets the reserve's space, so the database opens."""
    if shutil.disk_usage(settings.data_dir).free < max(settings.disk_reserve_bytes, MIN_FLOOR_BYTES):
        release_reserve(settings)


class DiskWait:
    """A worker's wait while the data dir's disk is full: until space is freed, or else a backoff runs out;
    one log line when it starts and one when it ends (a crash-looping worker would log, and restart,
    forever). The wait between tries while no space comes back doubles from `min_backoff_s` (default
    WOSAC_POLL_S) to `max_backoff_s`."""

    def __init__(
        self,
        settings: Settings,
        stopping: Callable[[], bool] = lambda: False,
        min_backoff_s: float | None = None,
        max_backoff_s: float = 30.0,
    ):
        self.settings = settings
        self.stopping = stopping
        self.min_backoff_s = settings.poll_s if min_backoff_s is None else min_backoff_s
        self.max_backoff_s = max_backoff_s
        self.since: float | None = None
        self.backoff_s = self.min_backoff_s

    def wait(self, exc: BaseException) -> None:
        """Sleep until space was freed or the backoff ran out (then the caller tries again)."""
        if self.since is None:
            self.since = time.monotonic()
            self.backoff_s = self.min_backoff_s
            log.warning("worker %s: the data dir's disk is full (%s); waiting for space", os.getpid(), exc)
        free = self._free()
        deadline = time.monotonic() + self.backoff_s
        while time.monotonic() < deadline and not self.stopping():
            time.sleep(min(self.settings.poll_s, self.backoff_s, 1.0))
            if self._free() > free + MIN_FLOOR_BYTES:  # space came back: try again at once
                break
        self.backoff_s = min(self.backoff_s * 2, self.max_backoff_s)

    def _free(self) -> int:
        return shutil.disk_usage(self.settings.data_dir).free

    def recovered(self) -> None:
        if self.since is not None:
            log.warning(
                "worker %s: space is back after %.0f s of a full disk; going on",
                os.getpid(),
                time.monotonic() - self.since,
            )
            self.since = None

    def until_written(self, write: Callable[[], object]):
        """`write()`, again after each wait while it fails for a full disk (until the worker stops)."""
        while True:
            try:
                result = write()
            except Exception as exc:
                if not is_disk_full(exc) or self.stopping():
                    raise
                self.wait(exc)
                continue
            self.recovered()
            return result


def full_now(settings: Settings) -> bool:
    """Whether the data dir's disk has less than `MIN_FLOOR_BYTES` free (False when it cannot be read)."""
    try:
        return shutil.disk_usage(settings.data_dir).free < MIN_FLOOR_BYTES
    except OSError:
        return False
