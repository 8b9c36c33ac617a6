"""Each scenario's criticality, kept between runs: scoring a scenario set again does not rate its scenes again.

A scene's criticality (`criticality_scores.scene_criticality`) depends on its
logged scenario alone, never on a submission, so scoring checkpoint after
checkpoint against the same validation set computed the same values every time
(about a twelfth of the whole path, `docs/speed.md`). They are kept in one
SQLite file under the user's cache folder, keyed by

- the scenario record's content: its id, length and CRC-32C (a rewritten record
  is a new key; the file it lives in does not matter), and
- this code's version: a digest of the package version and of the two modules
  that compute the value, so a changed formula never reads an old one.

The cache never stands in the way: where its file cannot be opened, read or
written (a read-only home, a damaged file, a lock held past a timeout), this
process goes on computing, after one warning. `WOSAC_CRITICALITY_CACHE=off`
turns it off; a path puts the file there. The oldest rows go past `MAX_ROWS`.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.util
import json
import os
import sqlite3
import threading
import warnings
from collections.abc import Iterable, Iterator
from pathlib import Path

import google_crc32c

from wosac_eval import __version__
from wosac_eval.runtime.cache_dirs import configured_cache

ENV = "WOSAC_CRITICALITY_CACHE"
MAX_ROWS = 250_000  # about 1 KB each: five validation sets
LOCK_TIMEOUT_S = 30.0  # SQLite waits this long for another process's write

RecordKey = tuple[str, int, int]  # (scenario_id, record length, CRC-32C of the record)


def record_key(scenario_id: str, record: bytes) -> RecordKey:
    """The cache key of a serialized `Scenario` (about 0.04 ms for a 1 MB record: one hardware CRC pass)."""
    return scenario_id, len(record), google_crc32c.value(record)


RATED_BY = ("wosac_eval.analysis.criticality_features", "wosac_eval.analysis.criticality_scores")


@functools.cache
def code_version() -> str:
    """The version of the code that computes a scene's criticality, as it is installed: the package's
    version and the source of the modules `RATED_BY` names (read as files, not imported)."""
    digest = hashlib.sha256(__version__.encode())
    for name in RATED_BY:
        spec = importlib.util.find_spec(name)
        digest.update(Path(str(spec.origin if spec else name)).read_bytes())
    return digest.hexdigest()[:16]


def cache_path() -> Path | None:
    """Where the cache lives (`$WOSAC_CRITICALITY_CACHE`, else the user's cache folder); None when off."""
    return configured_cache(ENV, "criticality.sqlite3")


class CriticalityCache:
    """The scenes' criticality in one SQLite file, shared by every process of a machine."""

    def __init__(self, path: Path, version: str | None = None) -> None:
        self.path = path
        self.version = version or code_version()
        path.parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(path, timeout=LOCK_TIMEOUT_S, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")  # readers never wait for a writer
        self._db.execute("PRAGMA synchronous=NORMAL")  # a cache: a power cut may lose its last rows, no more
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS scenes (version TEXT NOT NULL, scenario_id TEXT NOT NULL,"
            " length INTEGER NOT NULL, crc INTEGER NOT NULL, criticality TEXT NOT NULL,"
            " UNIQUE (scenario_id, length, crc, version))"
        )

    def get(self, key: RecordKey) -> dict | None:
        """The scene's criticality, or None when this version never computed it for this record."""
        found = self._db.execute(
            "SELECT criticality FROM scenes WHERE scenario_id = ? AND length = ? AND crc = ? AND version = ?",
            (*key, self.version),
        ).fetchone()
        return None if found is None else json.loads(found[0])

    def put(self, rows: Iterable[tuple[RecordKey, dict]]) -> None:
        """Keeps scenes' criticality (one transaction), dropping the oldest rows past `MAX_ROWS`."""
        values = [(self.version, *key, json.dumps(row)) for key, row in rows]
        if not values:
            return
        with self._transaction():
            self._db.executemany(
                "INSERT OR REPLACE INTO scenes (version, scenario_id, length, crc, criticality) VALUES (?, ?, ?, ?, ?)",
                values,
            )
            self._db.execute("DELETE FROM scenes WHERE rowid <= (SELECT MAX(rowid) FROM scenes) - ?", (MAX_ROWS,))

    @contextlib.contextmanager
    def _transaction(self) -> Iterator[None]:
        self._db.execute("BEGIN IMMEDIATE")  # the write lock first: no upgrade from a read can deadlock
        try:
            yield
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._db.execute("COMMIT")

    def close(self) -> None:
        self._db.close()


_local = threading.local()  # a connection per process and thread (SQLite's rule)


def process_cache() -> CriticalityCache | None:
    """This process's cache (opened once per process and thread), or None when off or unusable."""
    path = cache_path()
    state = getattr(_local, "state", None)
    if state is not None and state[0] == os.getpid() and state[1] == path:
        return state[2]
    cache = None
    if path is not None:
        try:
            cache = CriticalityCache(path)
        except (sqlite3.Error, OSError) as error:
            _unusable(path, error)
    _local.state = (os.getpid(), path, cache)
    return cache


def _unusable(path: Path | None, error: Exception) -> None:
    warnings.warn(
        f"the criticality cache {path} cannot be used ({error}); scenes are rated without it "
        f"(set {ENV}=off to silence this)",
        RuntimeWarning,
        stacklevel=3,
    )
    _local.state = (os.getpid(), path, None)


def cached(key: RecordKey) -> dict | None:
    """A scene's criticality from this process's cache, None when absent (or the cache unusable)."""
    cache = process_cache()
    if cache is None:
        return None
    try:
        return cache.get(key)
    except (sqlite3.Error, ValueError) as error:  # ValueError: a row that is not JSON (a damaged file)
        _unusable(cache.path, error)
        return None


def keep(rows: list[tuple[RecordKey, dict]]) -> None:
    """Keeps scenes' criticality in this process's cache, if it has one."""
    cache = process_cache()
    if cache is None or not rows:
        return
    try:
        cache.put(rows)
    except sqlite3.Error as error:
        _unusable(cache.path, error)


__all__ = ["CriticalityCache", "RecordKey", "record_key", "code_version", "cache_path", "cached", "keep", "ENV"]
