"""API keys (stored salted and hashed) and per-key quotas.

A key reads `wosac_<key id>_<secret>`. The id is stored in clear to find the
row; only a salted SHA-256 of the secret is stored, compared in constant time.
The secret carries 256 random bits, so a fast hash is enough (no password
stretching needed) and every request stays cheap.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import time
from dataclasses import dataclass

from .db import Store
from .names import display_name, name_key

KEY_PREFIX = "wosac_"
# Method names (and key names, the default method) as shown on the leaderboard.
METHOD_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9 ._+\-]{0,79}$"
DAY_S = 24 * 3600.0
ACTIVE_STATES = ("queued", "validating", "scoring")


@dataclass(frozen=True)
class ApiKey:
    id: str
    name: str
    max_concurrent: int
    max_daily: int
    max_daily_bytes: int


class QuotaExceeded(Exception):
    """A per-key quota refused the request; `status` is 429 (rate) or 413 (bytes)."""

    def __init__(self, status: int, message: str, retry_after_s: int | None = None):
        super().__init__(message)
        self.status = status
        self.message = message
        self.retry_after_s = retry_after_s


def _hash(salt: str, secret: str) -> str:
    return hashlib.sha256(bytes.fromhex(salt) + secret.encode()).hexdigest()


def create_key(store: Store, name: str, *, max_concurrent: int, max_daily: int, max_daily_bytes: int) -> str:
    """Insert a new key and return it in clear (the only time it is ever visible). The name is stored
    trimmed; a name that is another key's under its normal form (case, spacing, look-alike characters:
    names.name_key) is refused like the same name."""
    key_id = secrets.token_hex(6)
    secret = secrets.token_urlsafe(32)
    salt = secrets.token_hex(16)
    name = display_name(name)
    with store.transaction():
        same = store.fetchone("SELECT name FROM api_keys WHERE name = ? OR name_key = ?", (name, name_key(name)))
        if same is not None:
            raise ValueError(
                f"an API key named {same['name']!r} already exists"
                + ("" if same["name"] == name else f" (the same name as {name!r})")
            )
        store.execute(
            "INSERT INTO api_keys (id, name, name_key, salt, key_hash, created_at, revoked_at, max_concurrent,"
            " max_daily, max_daily_bytes) VALUES (?, ?, ?, ?, ?, ?, NULL, ?, ?, ?)",
            (
                key_id,
                name,
                name_key(name),
                salt,
                _hash(salt, secret),
                time.time(),
                max_concurrent,
                max_daily,
                max_daily_bytes,
            ),
        )
    return f"{KEY_PREFIX}{key_id}_{secret}"


def revoke_key(store: Store, name: str) -> bool:
    return (
        store.execute("UPDATE api_keys SET revoked_at = ? WHERE name = ? AND revoked_at IS NULL", (time.time(), name))
        == 1
    )


def list_keys(store: Store) -> list[dict]:
    return store.fetchall(
        "SELECT id, name, created_at, revoked_at, max_concurrent, max_daily, max_daily_bytes"
        " FROM api_keys ORDER BY created_at"
    )


def verify_key(store: Store, presented: str) -> ApiKey | None:
    """The key's row when `presented` is a valid, unrevoked key; None otherwise."""
    if not presented.startswith(KEY_PREFIX):
        return None
    key_id, sep, secret = presented[len(KEY_PREFIX) :].partition("_")
    if not sep or not secret or len(key_id) != 12:
        return None
    row = store.fetchone("SELECT * FROM api_keys WHERE id = ? AND revoked_at IS NULL", (key_id,))
    if row is None:
        # Hash anyway so an unknown id costs the same time as a wrong secret.
        _hash("00" * 16, secret)
        return None
    if not hmac.compare_digest(_hash(row["salt"], secret), row["key_hash"]):
        return None
    return ApiKey(row["id"], row["name"], row["max_concurrent"], row["max_daily"], row["max_daily_bytes"])


def remaining_daily_bytes(
    store: Store, key: ApiKey, now: float | None = None, exclude_upload: str | None = None
) -> int:
    """The key's daily byte quota less its submissions of the last 24 h and its unfinished resumable
    uploads (each at its declared length, or what it holds), but for `exclude_upload` (being completed)."""
    now = time.time() if now is None else now
    row = store.fetch_aggregate(
        "SELECT COALESCE(SUM(upload_bytes), 0) AS used FROM submissions WHERE key_id = ? AND created_at > ?",
        (key.id, now - DAY_S),
    )
    held = store.fetch_aggregate(
        "SELECT COALESCE(SUM(CASE WHEN declared_length IS NOT NULL AND declared_length > received_bytes"
        " THEN declared_length ELSE received_bytes END), 0) AS held FROM uploads"
        " WHERE key_id = ? AND submission_id IS NULL AND id != ?",
        (key.id, exclude_upload or ""),
    )
    return max(0, key.max_daily_bytes - int(row["used"]) - int(held["held"]))


def check_submission_quota(
    store: Store,
    key: ApiKey,
    upload_bytes: int = 0,
    now: float | None = None,
    *,
    pending: int = 0,
    held_bytes: int = 0,
    exclude_upload: str | None = None,
) -> None:
    """Raise QuotaExceeded when `key` may not start one more job of `upload_bytes` now.

    Call it inside the transaction that inserts the job so two racing uploads
    cannot both take the last slot. `pending`, `held_bytes`: the job slots and daily bytes held by the
    key's other uploads in flight (granted reservations, `service.Holds`): each may become a job, so
    they count against the unfinished jobs, the day's submissions and the day's bytes.
    """
    now = time.time() if now is None else now
    active = (
        store.fetch_aggregate(
            "SELECT COUNT(*) AS n FROM submissions WHERE key_id = ? AND state IN (?, ?, ?)", (key.id, *ACTIVE_STATES)
        )["n"]
        + pending
    )
    if active >= key.max_concurrent:
        raise QuotaExceeded(
            429,
            f"key {key.name!r} already has {active} unfinished submission(s); "
            f"its limit is {key.max_concurrent} at a time. Retry when one finishes.",
            30,
        )
    recent = store.fetchall(
        "SELECT created_at FROM submissions WHERE key_id = ? AND created_at > ? ORDER BY created_at",
        (key.id, now - DAY_S),
    )
    if len(recent) + pending >= key.max_daily:
        retry = int(recent[0]["created_at"] + DAY_S - now) + 1 if len(recent) >= key.max_daily else 30
        raise QuotaExceeded(
            429,
            f"key {key.name!r} made {len(recent)} submissions in the last 24 h"
            + (f" and has {pending} more on their way" if pending else "")
            + f"; its limit is {key.max_daily} per day.",
            retry,
        )
    if upload_bytes > remaining_daily_bytes(store, key, now, exclude_upload) - held_bytes:
        raise QuotaExceeded(
            413,
            f"this upload ({upload_bytes} bytes) exceeds what remains of key "
            f"{key.name!r}'s daily byte quota ({key.max_daily_bytes} bytes per 24 h).",
        )
