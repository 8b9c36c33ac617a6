"""A small store over the DB-API: SQLite (WAL, one file) or PostgreSQL (psycopg 3).

SQL in this package is written once, portably, with `?` placeholders; the
PostgreSQL path rewrites them to `%s`. Column types are the ones both engines
understand (TEXT, INTEGER, BIGINT, DOUBLE PRECISION), times are float epoch
seconds, ids are server-generated hex strings. Connections are per thread, so
the API's thread pool and a worker's heartbeat thread never share one.
"""

from __future__ import annotations

import contextlib
import logging
import sqlite3
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from .names import name_key

SCHEMA_VERSION = 5

SCHEMA = [
    """CREATE TABLE IF NOT EXISTS api_keys (
        id TEXT PRIMARY KEY,
        name TEXT NOT NULL UNIQUE,
        salt TEXT NOT NULL,
        key_hash TEXT NOT NULL,
        created_at DOUBLE PRECISION NOT NULL,
        revoked_at DOUBLE PRECISION,
        max_concurrent INTEGER NOT NULL,
        max_daily INTEGER NOT NULL,
        max_daily_bytes BIGINT NOT NULL
    )""",
    """CREATE TABLE IF NOT EXISTS submissions (
        id TEXT PRIMARY KEY,
        key_id TEXT NOT NULL,
        method TEXT NOT NULL,
        config TEXT NOT NULL,
        allow_partial INTEGER NOT NULL,
        published INTEGER NOT NULL,
        state TEXT NOT NULL,
        file_name TEXT NOT NULL,
        upload_bytes BIGINT NOT NULL,
        created_at DOUBLE PRECISION NOT NULL,
        updated_at DOUBLE PRECISION NOT NULL,
        started_at DOUBLE PRECISION,
        finished_at DOUBLE PRECISION,
        scenarios_done INTEGER NOT NULL,
        scenarios_total INTEGER,
        attempts INTEGER NOT NULL,
        lease_owner TEXT,
        lease_expires DOUBLE PRECISION,
        error TEXT,
        report TEXT,
        realism_meta_metric DOUBLE PRECISION,
        buckets TEXT
    )""",
    "CREATE INDEX IF NOT EXISTS submissions_state ON submissions (state, created_at)",
    "CREATE INDEX IF NOT EXISTS submissions_key ON submissions (key_id, created_at)",
    """CREATE TABLE IF NOT EXISTS uploads (
        id TEXT PRIMARY KEY,
        key_id TEXT NOT NULL,
        method TEXT NOT NULL,
        config TEXT NOT NULL,
        allow_partial INTEGER NOT NULL,
        published INTEGER NOT NULL,
        declared_length BIGINT,
        received_bytes BIGINT NOT NULL,
        created_at DOUBLE PRECISION NOT NULL,
        updated_at DOUBLE PRECISION NOT NULL,
        submission_id TEXT
    )""",
    "CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)",
]
# Schema changes after version 1, each applied once, in order: version -> statements (SQL text, or a
# function of the store for what SQL cannot compute).
MIGRATIONS: dict[int, list[str | Callable[[Store], None]]] = {
    2: [  # the challenge of every submission and upload; the share of the scenario set a result covers
        "ALTER TABLE submissions ADD COLUMN challenge TEXT NOT NULL DEFAULT 'sim_agents'",
        "ALTER TABLE uploads ADD COLUMN challenge TEXT NOT NULL DEFAULT 'sim_agents'",
        "ALTER TABLE submissions ADD COLUMN coverage DOUBLE PRECISION",
    ],
    3: [  # who owns a leaderboard name; an upload's state (race-free PATCH/complete/DELETE); what a job used
        """CREATE TABLE IF NOT EXISTS method_names (
            challenge TEXT NOT NULL,
            method TEXT NOT NULL,
            key_id TEXT NOT NULL,
            claimed_at DOUBLE PRECISION NOT NULL,
            PRIMARY KEY (challenge, method)
        )""",
        "ALTER TABLE uploads ADD COLUMN state TEXT NOT NULL DEFAULT 'open'",
        "ALTER TABLE submissions ADD COLUMN peak_rss_bytes BIGINT",
        "ALTER TABLE submissions ADD COLUMN cpu_s DOUBLE PRECISION",
    ],
    4: [  # names are owned by their normal form (names.name_key): `Team  Rocket` is `Team Rocket`'s
        "ALTER TABLE method_names ADD COLUMN name_key TEXT",
        "ALTER TABLE api_keys ADD COLUMN name_key TEXT",
        lambda store: _fill_name_keys(store),
        "CREATE UNIQUE INDEX IF NOT EXISTS method_names_name_key ON method_names (challenge, name_key)",
        "CREATE INDEX IF NOT EXISTS api_keys_name_key ON api_keys (name_key)",
    ],
    5: [  # a tus upload's Upload-Metadata as its client sent it (HEAD gives it back)
        "ALTER TABLE uploads ADD COLUMN metadata TEXT",
    ],
}


def _fill_name_keys(store: Store) -> None:
    """The normal form of every key name and claimed method name (computed here: SQL has no NFKC).
    Look-alike claims made before version 4 (`Team Rocket` by one key, `Team  Rocket` by another):
    the first claim keeps the name, the later ones are dropped (logged); their submissions stay, and
    the leaderboard shows a name's results of its owner only (jobs.leaderboard)."""
    for row in store.fetchall("SELECT id, name FROM api_keys"):
        store.execute("UPDATE api_keys SET name_key = ? WHERE id = ?", (name_key(row["name"]), row["id"]))
    kept: set[tuple[str, str]] = set()
    for row in store.fetchall("SELECT challenge, method, key_id FROM method_names ORDER BY claimed_at, method"):
        form = (row["challenge"], name_key(row["method"]))
        if form in kept:
            logging.getLogger(__name__).warning(
                "leaderboard name %r (%s) of key %s looks like an earlier claim: dropped, the name stays "
                "with its first owner (wosac-server methods assign to change that)",
                row["method"],
                row["challenge"],
                row["key_id"],
            )
            store.execute(
                "DELETE FROM method_names WHERE challenge = ? AND method = ?", (row["challenge"], row["method"])
            )
            continue
        kept.add(form)
        store.execute(
            "UPDATE method_names SET name_key = ? WHERE challenge = ? AND method = ?",
            (form[1], row["challenge"], row["method"]),
        )


class Store:
    """One database, reached through per-thread DB-API connections."""

    def __init__(self, url: str):
        self.url = url
        if url.startswith("sqlite:///"):
            self.dialect = "sqlite"
            self.sqlite_path = Path(url[len("sqlite:///") :])
        elif url.startswith(("postgresql://", "postgres://")):
            self.dialect = "postgresql"
        else:
            raise ValueError(f"unsupported WOSAC_DB_URL {url!r}: use sqlite:///PATH or postgresql://...")
        self._local = threading.local()

    # -- connections -------------------------------------------------------------
    def _connect(self):
        if self.dialect == "sqlite":
            self.sqlite_path.parent.mkdir(parents=True, exist_ok=True)
            # isolation_level=None: we issue BEGIN ourselves, so a read never holds a lock.
            conn = sqlite3.connect(self.sqlite_path, timeout=60.0, isolation_level=None, check_same_thread=False)
            conn.row_factory = sqlite3.Row
            conn.execute("PRAGMA journal_mode=WAL")
            # FULL: a COMMIT is on disk before we answer 202 (durability over a few ms).
            conn.execute("PRAGMA synchronous=FULL")
            conn.execute("PRAGMA busy_timeout=60000")
            return conn
        import psycopg
        from psycopg.rows import dict_row

        return psycopg.connect(self.url, autocommit=True, row_factory=dict_row)

    def _conn(self):
        conn = getattr(self._local, "conn", None)
        if conn is not None and self.dialect == "postgresql" and (conn.closed or conn.broken):
            conn = None  # the server restarted or the link dropped: reconnect on next use
        if conn is None:
            conn = self._connect()
            self._local.conn = conn
        return conn

    def close(self) -> None:
        conn = getattr(self._local, "conn", None)
        if conn is not None:
            with contextlib.suppress(Exception):  # closing a broken connection may fail; it is dropped either way
                conn.close()
            self._local.conn = None

    def _sql(self, sql: str) -> str:
        return sql.replace("?", "%s") if self.dialect == "postgresql" else sql

    # -- statements ----------------------------------------------------------------
    def _run(self, sql: str, params: Sequence[Any]):
        try:
            return self._conn().execute(self._sql(sql), tuple(params))
        except Exception as exc:
            # A dropped PostgreSQL connection outside a transaction: one retry on a new one.
            if self.dialect != "postgresql" or getattr(self._local, "in_tx", False):
                raise
            import psycopg

            if not isinstance(exc, psycopg.OperationalError):
                raise
            self.close()
            return self._conn().execute(self._sql(sql), tuple(params))

    def execute(self, sql: str, params: Sequence[Any] = ()) -> int:
        """Run one statement; returns the affected row count."""
        return self._run(sql, params).rowcount

    def fetchall(self, sql: str, params: Sequence[Any] = ()) -> list[dict]:
        return [dict(r) for r in self._run(sql, params).fetchall()]

    def fetchone(self, sql: str, params: Sequence[Any] = ()) -> dict | None:
        rows = self.fetchall(sql, params)
        return rows[0] if rows else None

    def fetch_aggregate(self, sql: str, params: Sequence[Any] = ()) -> dict:
        """The row of an aggregate query (COUNT, SUM without GROUP BY), which always answers one."""
        row = self.fetchone(sql, params)
        if row is None:
            raise LookupError(f"an aggregate query answered no row: {sql}")
        return row

    @contextlib.contextmanager
    def transaction(self) -> Iterator[Store]:
        """A write transaction; on SQLite it takes the write lock up front (BEGIN IMMEDIATE)
        so check-then-insert sequences (quotas) cannot interleave."""
        conn = self._conn()
        if self.dialect == "sqlite":
            conn.execute("BEGIN IMMEDIATE")
            try:
                yield self
            except BaseException:
                conn.execute("ROLLBACK")
                raise
            try:
                conn.execute("COMMIT")
            except BaseException:
                # A COMMIT that failed (SQLITE_FULL: the disk is full) leaves the transaction open; the
                # thread's connection could then never begin another one.
                if conn.in_transaction:
                    conn.execute("ROLLBACK")
                raise
        else:
            self._local.in_tx = True
            try:
                with conn.transaction():
                    yield self
            finally:
                self._local.in_tx = False

    def migrate(self) -> None:
        """Create the tables (version 1), then apply every later migration once."""
        with self.transaction():
            for stmt in SCHEMA:
                self.execute(stmt)
            row = self.fetchone("SELECT version FROM schema_version")
            if row is None:
                self.execute("INSERT INTO schema_version (version) VALUES (1)")
            version = 1 if row is None else int(row["version"])
            for target in sorted(v for v in MIGRATIONS if v > version):
                for step in MIGRATIONS[target]:
                    if callable(step):
                        step(self)
                    else:
                        self.execute(step)
                self.execute("UPDATE schema_version SET version = ?", (target,))

    def ping(self) -> bool:
        return self.fetchone("SELECT 1 AS ok") is not None
