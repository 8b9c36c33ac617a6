"""The job queue: submission rows, their life cycle, leases and the reaper.

Life cycle: queued -> validating (claimed by a worker) -> scoring -> done | failed.
A claim is a compare-and-set UPDATE (`... WHERE id = ? AND state = 'queued'`),
atomic on both SQLite and PostgreSQL, so two workers never run the same job.
A claimed job carries a lease (`lease_owner`, `lease_expires`) that the worker
renews while it scores; when a worker dies the lease goes stale and the reaper
(run by every worker before it polls) puts the job back in the queue, or fails
it once it has been interrupted `max_attempts` times.
"""

from __future__ import annotations

import json
import os
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from .db import Store
from .models import is_partial
from .names import display_name, name_key

STATES = ("queued", "validating", "scoring", "done", "failed")
RUNNING = ("validating", "scoring")


def new_id() -> str:
    """A server-generated id; also the stem of every file stored for it."""
    return uuid.uuid4().hex


def without_paths(value, swaps: list[tuple[str, str]]):
    """`value` (a string, or dicts and lists of them) with every `(path, name)` of `swaps` replaced, longest
    path first so that a path is replaced whole before any folder of it: what a client may see."""
    swaps = sorted((pair for pair in swaps if pair[0] not in (os.sep, "." + os.sep)), key=lambda p: -len(p[0]))

    def redact(v):
        if isinstance(v, dict):
            return {k: redact(x) for k, x in v.items()}
        if isinstance(v, list):
            return [redact(x) for x in v]
        if isinstance(v, str):
            for old, new in swaps:
                v = v.replace(old, new)
        return v

    return redact(value)


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_json_atomically(path: Path, payload: dict) -> None:
    """Write, fsync, rename: a reader sees the old file or the whole new one, never half."""
    tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
    with open(tmp, "w") as f:
        json.dump(payload, f, allow_nan=True)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    fsync_dir(path.parent)


@dataclass(frozen=True)
class SubmissionParams:
    """What a submission asks for, however sent (query parameters, or a tus upload's `Upload-Metadata`):
    `config` and `method` None until the service resolves them (the challenge's current config, the key's
    name)."""

    challenge: str = "sim_agents"
    config: str | None = None
    method: str | None = None
    publish: bool = False
    allow_partial: bool = False


# -- submissions ----------------------------------------------------------------------
def insert_submission(
    store: Store, submission_id: str, key_id: str, params: SubmissionParams, *, file_name: str, upload_bytes: int
) -> None:
    """A queued job of resolved `params` (its config and method set)."""
    now = time.time()
    store.execute(
        "INSERT INTO submissions (id, key_id, method, challenge, config, allow_partial, published, state,"
        " file_name, upload_bytes, created_at, updated_at, scenarios_done, attempts)"
        " VALUES (?, ?, ?, ?, ?, ?, ?, 'queued', ?, ?, ?, ?, 0, 0)",
        (
            submission_id,
            key_id,
            params.method,
            params.challenge,
            params.config,
            int(params.allow_partial),
            int(params.publish),
            file_name,
            upload_bytes,
            now,
            now,
        ),
    )


def get_submission(store: Store, submission_id: str) -> dict | None:
    return store.fetchone("SELECT * FROM submissions WHERE id = ?", (submission_id,))


def list_submissions(store: Store, key_id: str, limit: int = 100) -> list[dict]:
    return store.fetchall(
        "SELECT * FROM submissions WHERE key_id = ? ORDER BY created_at DESC LIMIT ?", (key_id, limit)
    )


def claim_next(store: Store, owner: str, lease_s: float) -> dict | None:
    """Take the oldest queued job for `owner`, or None when the queue is empty."""
    for _ in range(16):  # lost races only; each retry sees a newer queue head
        head = store.fetchone("SELECT id FROM submissions WHERE state = 'queued' ORDER BY created_at, id LIMIT 1")
        if head is None:
            return None
        now = time.time()
        won = store.execute(
            "UPDATE submissions SET state = 'validating', lease_owner = ?, lease_expires = ?,"
            " attempts = attempts + 1, started_at = ?, updated_at = ?, scenarios_done = 0"
            " WHERE id = ? AND state = 'queued'",
            (owner, now + lease_s, now, now, head["id"]),
        )
        if won == 1:
            return get_submission(store, head["id"])
    return None


def renew_lease(store: Store, submission_id: str, owner: str, lease_s: float) -> bool:
    """Extend the lease; False means the job is no longer ours (the reaper took it back)."""
    now = time.time()
    return (
        store.execute(
            "UPDATE submissions SET lease_expires = ?, updated_at = ? WHERE id = ? AND lease_owner = ?"
            " AND state IN ('validating', 'scoring')",
            (now + lease_s, now, submission_id, owner),
        )
        == 1
    )


def record_progress(store: Store, submission_id: str, owner: str, done: int, total: int) -> bool:
    return (
        store.execute(
            "UPDATE submissions SET state = 'scoring', scenarios_done = ?, scenarios_total = ?, updated_at = ?"
            " WHERE id = ? AND lease_owner = ? AND state IN ('validating', 'scoring')",
            (done, total, time.time(), submission_id, owner),
        )
        == 1
    )


def finish_done(store: Store, submission_id: str, owner: str, result: dict) -> bool:
    buckets = result.get("buckets") or {}
    meta = buckets.get("realism_meta_metric")
    n = len(result.get("scenarios") or [])
    coverage = (result.get("coverage") or {}).get("fraction")
    now = time.time()
    return (
        store.execute(
            "UPDATE submissions SET state = 'done', finished_at = ?, updated_at = ?, lease_owner = NULL,"
            " lease_expires = NULL, scenarios_done = ?, scenarios_total = ?, realism_meta_metric = ?,"
            " buckets = ?, coverage = ?, error = NULL WHERE id = ? AND lease_owner = ?",
            (
                now,
                now,
                n,
                n,
                None if meta is None else float(meta),
                json.dumps(buckets),
                None if coverage is None else float(coverage),
                submission_id,
                owner,
            ),
        )
        == 1
    )


def finish_failed(store: Store, submission_id: str, owner: str | None, error: str, report: dict | None = None) -> bool:
    now = time.time()
    owner_clause = "lease_owner = ?" if owner is not None else "lease_owner IS NULL"
    params = [now, now, error, None if report is None else json.dumps(report), submission_id]
    if owner is not None:
        params.append(owner)
    return (
        store.execute(
            "UPDATE submissions SET state = 'failed', finished_at = ?, updated_at = ?, lease_owner = NULL,"
            " lease_expires = NULL, error = ?, report = ? WHERE id = ? AND state IN ('queued', 'validating',"
            f" 'scoring') AND {owner_clause}",
            params,
        )
        == 1
    )


def release(store: Store, submission_id: str, owner: str) -> bool:
    """Give a job back to the queue on a clean shutdown (the attempt does not count)."""
    return (
        store.execute(
            "UPDATE submissions SET state = 'queued', lease_owner = NULL, lease_expires = NULL,"
            " attempts = attempts - 1, scenarios_done = 0, updated_at = ?"
            " WHERE id = ? AND lease_owner = ? AND state IN ('validating', 'scoring')",
            (time.time(), submission_id, owner),
        )
        == 1
    )


def reap_expired(store: Store, max_attempts: int, now: float | None = None) -> tuple[int, int]:
    """Re-queue jobs whose lease went stale; fail those interrupted `max_attempts` times.

    Returns (re-queued, failed). Safe to run from many processes at once: each
    UPDATE re-checks the stale lease in its WHERE clause.
    """
    now = time.time() if now is None else now
    failed = store.execute(
        "UPDATE submissions SET state = 'failed', finished_at = ?, updated_at = ?, lease_owner = NULL,"
        " lease_expires = NULL, error = ? WHERE state IN ('validating', 'scoring') AND lease_expires < ?"
        " AND attempts >= ?",
        (
            now,
            now,
            f"scoring was interrupted {max_attempts} times (its worker process died or stopped "
            "responding each time); giving up on this submission",
            now,
            max_attempts,
        ),
    )
    requeued = store.execute(
        "UPDATE submissions SET state = 'queued', lease_owner = NULL, lease_expires = NULL,"
        " scenarios_done = 0, updated_at = ? WHERE state IN ('validating', 'scoring') AND lease_expires < ?",
        (now, now),
    )
    return requeued, failed


def leaderboard(store: Store, config: str, challenge: str = "sim_agents") -> list[dict]:
    """Best published, finished submission per method of one challenge and config, best first."""
    rows = store.fetchall(
        "SELECT id, key_id, method, realism_meta_metric, buckets, coverage, finished_at FROM submissions"
        " WHERE state = 'done' AND published = 1 AND challenge = ? AND config = ?"
        " AND realism_meta_metric IS NOT NULL",
        (challenge, config),
    )
    # One row per name (look-alike spellings are one name), and only the owner's results under an owned
    # name: look-alikes published by another key before names were compared by their normal form stay off.
    owners = {
        r["name_key"]: r["key_id"]
        for r in store.fetchall("SELECT name_key, key_id FROM method_names WHERE challenge = ?", (challenge,))
    }
    best: dict[str, dict] = {}
    for r in rows:
        form = name_key(r["method"])
        if owners.get(form, r["key_id"]) != r["key_id"]:
            continue
        cur = best.get(form)
        if cur is None or (r["realism_meta_metric"], -r["finished_at"]) > (
            cur["realism_meta_metric"],
            -cur["finished_at"],
        ):
            best[form] = {**r, "method": display_name(r["method"])}
    ranked = sorted(best.values(), key=lambda r: (-r["realism_meta_metric"], r["finished_at"]))
    return [
        {
            "rank": i + 1,
            "method": r["method"],
            "submission_id": r["id"],
            "realism_meta_metric": r["realism_meta_metric"],
            "buckets": json.loads(r["buckets"] or "{}"),
            "coverage": r["coverage"],
            "partial": is_partial(r["coverage"]),
            "finished_at": r["finished_at"],
        }
        for i, r in enumerate(ranked)
    ]


def is_public(store: Store, row: dict) -> bool:
    """Whether anyone may see a submission's scene pages, as they see its leaderboard row: done, published,
    with a meta-metric, under a method name its own key owns (the leaderboard's rules, whatever its rank)."""
    if row["state"] != "done" or not row["published"] or row["realism_meta_metric"] is None:
        return False
    owner = store.fetchone(
        "SELECT key_id FROM method_names WHERE challenge = ? AND name_key = ?",
        (row["challenge"], name_key(row["method"])),
    )
    return owner is None or owner["key_id"] == row["key_id"]


# -- resumable uploads ------------------------------------------------------------------
def insert_upload(
    store: Store,
    upload_id: str,
    key_id: str,
    params: SubmissionParams,
    *,
    declared_length: int | None,
    metadata: str | None,
) -> None:
    """An open resumable upload of resolved `params`; `metadata`: tus's Upload-Metadata as sent, given back by HEAD."""
    now = time.time()
    store.execute(
        "INSERT INTO uploads (id, key_id, method, challenge, config, allow_partial, published, declared_length,"
        " received_bytes, created_at, updated_at, metadata) VALUES (?, ?, ?, ?, ?, ?, ?, ?, 0, ?, ?, ?)",
        (
            upload_id,
            key_id,
            params.method,
            params.challenge,
            params.config,
            int(params.allow_partial),
            int(params.publish),
            declared_length,
            now,
            now,
            metadata,
        ),
    )


def get_upload(store: Store, upload_id: str) -> dict | None:
    return store.fetchone("SELECT * FROM uploads WHERE id = ?", (upload_id,))


def held_upload(store: Store, upload_id: str) -> dict:
    """The row of an upload the caller moved out of `open` (to `writing` or `completing`): no other
    request removes it until the caller settles it."""
    row = get_upload(store, upload_id)
    if row is None:
        raise LookupError(f"upload {upload_id} vanished while held")
    return row


def set_upload_offset(store: Store, upload_id: str, received: int) -> None:
    store.execute(
        "UPDATE uploads SET received_bytes = ?, updated_at = ? WHERE id = ?", (received, time.time(), upload_id)
    )


def move_upload(store: Store, upload_id: str, from_state: str, to_state: str) -> bool:
    """Compare-and-set of an upload's state (open -> writing -> open, open -> completing -> complete):
    atomic in the database, so at most one PATCH, complete or DELETE works on an upload at a time,
    whichever API process or request gets there first."""
    return (
        store.execute(
            "UPDATE uploads SET state = ?, updated_at = ? WHERE id = ? AND state = ?",
            (to_state, time.time(), upload_id, from_state),
        )
        == 1
    )


def reopen_interrupted_uploads(store: Store) -> int:
    """Uploads left writing or completing by an API process that died: open again (its requests are gone)."""
    return store.execute(
        "UPDATE uploads SET state = 'open' WHERE state IN ('writing', 'completing') AND submission_id IS NULL"
    )


def deleting_uploads(store: Store) -> list[str]:
    """Uploads whose DELETE removed the file but could not drop the row (the disk was full)."""
    return [r["id"] for r in store.fetchall("SELECT id FROM uploads WHERE state = 'deleting'")]


def drop_upload(store: Store, upload_id: str) -> None:
    store.execute("DELETE FROM uploads WHERE id = ?", (upload_id,))


def open_uploads(store: Store, key_id: str) -> int:
    return store.fetch_aggregate(
        "SELECT COUNT(*) AS n FROM uploads WHERE key_id = ? AND submission_id IS NULL AND state != 'deleting'",
        (key_id,),
    )["n"]


def expired_uploads(store: Store, older_than: float) -> list[dict]:
    return store.fetchall("SELECT id FROM uploads WHERE submission_id IS NULL AND updated_at < ?", (older_than,))


# -- leaderboard names -------------------------------------------------------------------
# Owned by their normal form (names.name_key): `Team  Rocket` and `team rocket` are `Team Rocket`.
def method_owner(store: Store, challenge: str, method: str) -> str | None:
    """The key id owning a leaderboard name (or a look-alike of it) of a challenge, or None while nobody used it."""
    row = store.fetchone(
        "SELECT key_id FROM method_names WHERE challenge = ? AND name_key = ?", (challenge, name_key(method))
    )
    return None if row is None else row["key_id"]


def claim_method(store: Store, challenge: str, method: str, key_id: str) -> bool:
    """Take a free name for `key_id` (no-op when it has it, under any look-alike spelling); False when another
    key owns it. Call inside the transaction that inserts the submission."""
    store.execute(
        "INSERT INTO method_names (challenge, method, name_key, key_id, claimed_at) VALUES (?, ?, ?, ?, ?)"
        " ON CONFLICT DO NOTHING",
        (challenge, display_name(method), name_key(method), key_id, time.time()),
    )
    return method_owner(store, challenge, method) == key_id


def assign_method(store: Store, challenge: str, method: str, key_id: str | None) -> None:
    """The operator's override: give a name (and its look-alikes) to another key, or free it (key_id None)."""
    with store.transaction():
        store.execute("DELETE FROM method_names WHERE challenge = ? AND name_key = ?", (challenge, name_key(method)))
        if key_id is not None:
            store.execute(
                "INSERT INTO method_names (challenge, method, name_key, key_id, claimed_at) VALUES (?, ?, ?, ?, ?)",
                (challenge, display_name(method), name_key(method), key_id, time.time()),
            )


def list_methods(store: Store) -> list[dict]:
    return store.fetchall(
        "SELECT m.challenge, m.method, k.name AS key_name, m.claimed_at FROM method_names m"
        " LEFT JOIN api_keys k ON k.id = m.key_id ORDER BY m.challenge, m.method"
    )
