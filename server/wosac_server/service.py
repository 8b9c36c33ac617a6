"""The service layer: the service's state and the rules every route applies (keys, quotas, ownership,
disk space, acceptance), between the routes (HTTP) and storage (`jobs`, `results`, the data dir).

One `Service` per API process (`app.state.service`): the settings, the job store, the holds of
uploads in flight. Routes reach it through the `service` dependency and authenticate with
`current_key`; it refuses with the domain errors of `errors`, which `routes.answers` alone turns into
status codes. Its parts: `intake` (a whole body received), `resumable` (tus uploads), `reading`
(statuses, results, scenes).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import dataclasses
import logging
import os
import re
import shutil
import threading
import time
from pathlib import Path
from typing import Annotated

from fastapi import Depends, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from wosac_eval.metrics.config import config_name_for
from wosac_eval.parse.archive import check_container
from wosac_eval.parse.errors import ParseError
from wosac_eval.parse.shards import NotASubmissionError

from . import auth, disk, jobs
from .db import Store
from .errors import Invalid, NotASubmission, NotFound, NotOwner, TooLarge, TooMany, Unauthenticated
from .holds import Hold, Holds
from .jobs import SubmissionParams
from .names import display_name, name_key
from .settings import Settings

ID_PATTERN = r"^[0-9a-f]{32}$"

log = logging.getLogger("wosac_server.service")

bearer = HTTPBearer(auto_error=False, description="An API key from `wosac-server keys create`.")


class Service:
    """Settings, store and the checks shared by the routes."""

    def __init__(self, settings: Settings):
        self.settings = settings
        settings.ensure_dirs()
        disk.release_reserve_if_low(settings)  # a full disk: the start-up's database writes come first
        self.store = Store(settings.resolved_db_url)
        self.store.migrate()
        # Bodies of direct uploads cut short by a crash of a previous run: nobody will finish them.
        for orphan in settings.uploads_dir.glob("*.body"):
            orphan.unlink(missing_ok=True)
        # Decompressed copies that workers of earlier versions kept while scoring; none is made now.
        shutil.rmtree(settings.data_dir / "spool", ignore_errors=True)
        jobs.reopen_interrupted_uploads(self.store)
        for upload_id in jobs.deleting_uploads(self.store):  # DELETEs whose database write failed: finish them
            (settings.uploads_dir / f"{upload_id}.part").unlink(missing_ok=True)
            jobs.drop_upload(self.store, upload_id)
        # Upload states a request could not record (the disk was full): (from, to or None to drop the row).
        self.unsettled: dict[str, tuple[str, str | None]] = {}
        self._state_lock = threading.Lock()
        # Bodies of direct uploads being received: temp file -> declared length (their promised bytes).
        self._receiving: dict[Path, int] = {}
        # A space check and the promise it grants are one step (two uploads cannot both take the last room).
        self.space_gate = threading.Lock()
        disk.restore_reserve(settings, self.disk_state())
        self.limits = settings.input_limits()
        # Job slots and daily bytes held by uploads being received or checked now, granted before any work.
        self.holds = Holds()
        # Container checks decompress whole uploads: a few at a time, the rest wait without a thread.
        self.check_slots = asyncio.Semaphore(settings.upload_checks)
        self._auth_failures: dict[str, collections.deque] = {}
        self._auth_lock = threading.Lock()

    # -- what may be asked for ---------------------------------------------------------------
    def config_for(self, challenge: str, config: str | None) -> str:
        """The config a job is scored with: the asked one, or the challenge's current one; 422 when not served."""

        def refuse_unserved(name: str) -> None:
            if name not in self.settings.configs:
                raise Invalid(f"unknown config {name!r}; this server scores {self.settings.configs}")

        if config is not None:
            refuse_unserved(config)
        try:
            name = config_name_for(challenge, config)
        except ValueError as error:  # a preset of the other challenge: the library's rule
            raise Invalid(str(error)) from None
        refuse_unserved(name)
        return name

    def resolve(self, key: auth.ApiKey, asked: SubmissionParams) -> SubmissionParams:
        """The parameters a job is made with: its config (422 when not served) and its leaderboard name as
        stored (403 when another key owns it); runs in a thread (it reads the database)."""
        config = self.config_for(asked.challenge, asked.config)
        method = self.check_method(key, asked.challenge, asked.method or key.name)
        return dataclasses.replace(asked, config=config, method=method)

    # -- keys, quotas, ownership ---------------------------------------------------------------
    def key_for(self, creds: HTTPAuthorizationCredentials | None, client: str = "") -> auth.ApiKey:
        if creds is None or creds.scheme.lower() != "bearer":
            raise Unauthenticated("missing API key: send 'Authorization: Bearer <key>'", sent_a_key=False)
        self._refuse_guessing(client)
        key = auth.verify_key(self.store, creds.credentials)
        if key is None:
            self._record_auth_failure(client)
            raise Unauthenticated("unknown or revoked API key", sent_a_key=True)
        return key

    def _recent_failures(self, client: str, now: float) -> collections.deque:
        failures = self._auth_failures.setdefault(client, collections.deque())
        while failures and failures[0] < now - 60.0:
            failures.popleft()
        return failures

    def _refuse_guessing(self, client: str) -> None:
        """429 for an address past its failed authentications of the last minute (keys are not guessed)."""
        now = time.monotonic()
        with self._auth_lock:
            failures = self._recent_failures(client, now)
            if len(failures) < self.settings.auth_failures_per_minute:
                return
            retry = int(failures[0] + 60.0 - now) + 1
        raise TooMany(
            f"too many failed authentications from this address in the last minute; retry in {retry} s",
            retry_after_s=retry,
        )

    def _record_auth_failure(self, client: str) -> None:
        now = time.monotonic()
        with self._auth_lock:
            if len(self._auth_failures) > 10_000:  # bounded: forget addresses quiet for a minute
                for address in [a for a, f in self._auth_failures.items() if not f or f[-1] < now - 60.0]:
                    del self._auth_failures[address]
            self._recent_failures(client, now).append(now)

    @staticmethod
    def quota_error(exc: auth.QuotaExceeded) -> TooMany | TooLarge:
        kind = TooMany if exc.status == 429 else TooLarge
        return kind(exc.message, retry_after_s=exc.retry_after_s or None)

    def own_submission(self, key: auth.ApiKey, submission_id: str) -> dict:
        # 404 (not 403) for another user's id: ids of others are not even confirmed to exist.
        row = jobs.get_submission(self.store, submission_id) if re.match(ID_PATTERN, submission_id) else None
        if row is None or row["key_id"] != key.id:
            raise NotFound(f"no submission {submission_id!r} for this API key")
        return row

    def own_upload(self, key: auth.ApiKey, upload_id: str) -> dict:
        if self.unsettled:  # states left behind by a full disk are recorded before anyone looks at them
            self.retry_unsettled()
        row = jobs.get_upload(self.store, upload_id) if re.match(ID_PATTERN, upload_id) else None
        if row is None or row["key_id"] != key.id or row["state"] == "deleting":
            raise NotFound(f"no upload {upload_id!r} for this API key")
        return row

    def check_method(self, key: auth.ApiKey, challenge: str, method: str) -> str:
        """The leaderboard name as stored (names.display_name); 403 when another key owns it or a look-alike
        of it (same normal form, names.name_key), or it is another key's name, not yet used."""
        shown = display_name(method)
        owner = jobs.method_owner(self.store, challenge, shown)
        if owner is None:
            reserved = {
                r["id"] for r in self.store.fetchall("SELECT id FROM api_keys WHERE name_key = ?", (name_key(shown),))
            }
            owner = None if not reserved or key.id in reserved else reserved.pop()
        if owner is not None and owner != key.id:
            raise NotOwner(
                f"the method name {shown!r} (or a name differing from it only in case, "
                f"spacing or look-alike characters) belongs to another key on the {challenge} "
                "leaderboard; choose another name (an operator can reassign names: "
                "wosac-server methods)",
            )
        return shown

    @contextlib.asynccontextmanager
    async def upload_slot(self, key: auth.ApiKey, declared: int | None = None):
        """Hold one of the key's job slots (and `declared` bytes of its daily quota) while its upload is
        received and checked; 429 (413) when none is free. Only granted holds count, so of any number of
        uploads at once on a key with N free slots exactly N go on, and 40 uploads at once from a key
        allowed 2 jobs cost at most 2 checks. Yields the hold; `accept` turns it into the job."""
        hold = Hold(key.id, declared or 0)  # made here, so that it is released however the request ends
        try:
            await run_in_threadpool(self.reserve, key, hold)
            yield hold
        finally:
            self.holds.release(hold)  # a no-op once accepted (the job counts itself) or never granted

    def reserve(self, key: auth.ApiKey, hold: Hold) -> None:
        """Grant `hold`, or raise 429/413 (runs in a thread). The check and the grant are one step under the
        holds' gate, which `accept` also takes to commit a job and drop its hold: every check sees each
        slot once, as a hold or as a job row."""
        with self.holds.gate:
            self.refuse_early(key, hold.bytes or None, single=True)
            self.holds.grant(hold)

    def _check_quota(self, key: auth.ApiKey, size: int, hold: Hold | None, upload_id: str | None = None) -> None:
        """auth.check_submission_quota with the holds of the key's other uploads in flight."""
        slots, held_bytes = self.holds.held(key.id, but=hold)
        try:
            auth.check_submission_quota(
                self.store, key, size, pending=slots, held_bytes=held_bytes, exclude_upload=upload_id
            )
        except auth.QuotaExceeded as exc:
            raise self.quota_error(exc) from exc

    def upload_limit(
        self, key: auth.ApiKey, upload_id: str | None = None, hold: Hold | None = None, single: bool = False
    ) -> int:
        """Bytes the key may still send: the server's limit (of one request's body when `single`), its day's
        quota less what other uploads hold."""
        held = self.holds.held(key.id, but=hold)[1]
        left = auth.remaining_daily_bytes(self.store, key, exclude_upload=upload_id) - held
        return max(0, min(self._server_limit(single), left))

    def _server_limit(self, single: bool) -> int:
        if single:
            return min(self.settings.max_single_upload_bytes, self.settings.max_upload_bytes)
        return self.settings.max_upload_bytes

    def _single_limit_binds(self, limit: int) -> bool:
        """Whether a direct upload's `limit` is the single-request one, which a resumable upload escapes."""
        return (
            self.settings.max_single_upload_bytes < self.settings.max_upload_bytes
            and limit == self.settings.max_single_upload_bytes
        )

    def _single_refusal(self, what: str) -> TooLarge:
        return TooLarge(
            f"{what}, more than one request may carry ({self.settings.max_single_upload_bytes} "
            "bytes, WOSAC_MAX_SINGLE_UPLOAD_BYTES); send it with `wosac-eval submit`, which uploads "
            "it in resumable chunks",
        )

    def refuse_early(self, key: auth.ApiKey, declared: int | None, single: bool = False) -> None:
        """Quota and size checks before a single body byte is read: of a direct upload (`single`, under the
        gate, by `reserve`), or of a new resumable upload (which takes no job slot before `complete`)."""
        limit = self._server_limit(single)
        if declared is not None and declared > limit:
            if self._single_limit_binds(limit):
                raise self._single_refusal(f"the body is {declared} bytes")
            raise TooLarge(
                f"the body is {declared} bytes; this server accepts at most {limit} bytes (WOSAC_MAX_UPLOAD_BYTES)"
            )
        self._check_quota(key, 0, None)
        if declared is not None and declared > self.upload_limit(key):
            raise TooLarge(
                f"the body is {declared} bytes; key {key.name!r} has "
                f"{self.upload_limit(key)} bytes left of its daily quota",
            )

    def too_large(self, key: auth.ApiKey) -> TooLarge:
        """The 413 of a direct upload's body that went past `upload_limit(key, single=True)`."""
        limit = self.upload_limit(key, single=True)
        if self._single_limit_binds(limit):
            return self._single_refusal("the body is larger")
        return TooLarge(
            f"the body exceeds the {limit} bytes this key may upload now "
            f"(server limit {self.settings.max_upload_bytes} bytes, WOSAC_MAX_UPLOAD_BYTES)",
        )

    # -- disk space (see wosac_server.disk) ------------------------------------------------------
    def disk_state(self) -> disk.DiskState:
        """The data dir's disk now, with the bytes that open uploads, jobs and bodies in flight still need."""
        with self._state_lock:
            bodies = list(self._receiving.items())
        in_flight = 0
        for temp, declared in bodies:
            try:
                received = temp.stat().st_size
            except FileNotFoundError:  # just accepted (renamed): its job row counts it now
                continue
            in_flight += max(0, declared - received) + disk.job_need_bytes(declared)
        return disk.measure(self.settings, self.store, in_flight)

    def need_space(self, extra: int = 0) -> None:
        """507 (with Retry-After) when `extra` more bytes would take the disk past its floor."""
        state = self.disk_state()
        if state.room(extra) < 0:
            raise state.refusal()

    def admit_body(self, temp: Path, declared: int | None) -> None:
        """Count a direct upload's declared body (and its job's files) as promised while it is received;
        507 when there is no room. `forget_body` ends it."""
        declared = declared or 0
        with self.space_gate:
            self.need_space(declared + disk.job_need_bytes(declared))
            with self._state_lock:
                self._receiving[temp] = declared

    def forget_body(self, temp: Path) -> None:
        with self._state_lock:
            self._receiving.pop(temp, None)

    def write_state(self, write, *args):
        """`write(*args)`, a database write that must not be lost to a full disk: when it fails for space,
        the reserve file is freed and it is tried once more."""
        try:
            return write(*args)
        except Exception as exc:
            if not disk.is_disk_full(exc) or not disk.release_reserve(self.settings):
                raise
        return write(*args)

    def settle_upload(self, upload_id: str, from_state: str, to_state: str | None) -> None:
        """End a request's hold on an upload (`to_state` None: drop its row). Never raises: when even the
        reserve's space is not enough, the move is kept and retried (`retry_unsettled`), so no upload stays
        `writing`, `completing` or `deleting` once the database can write again."""
        try:
            self.write_state(self._settle, upload_id, from_state, to_state)
        except Exception as exc:  # noqa: BLE001 - the request's own answer must not be replaced by this
            log.warning(
                "could not record upload %s as %s (%s); retrying in the background",
                upload_id,
                to_state or "deleted",
                exc,
            )
            with self._state_lock:
                self.unsettled[upload_id] = (from_state, to_state)

    def _settle(self, upload_id: str, from_state: str, to_state: str | None) -> None:
        if to_state is None:
            jobs.drop_upload(self.store, upload_id)
        else:
            jobs.move_upload(self.store, upload_id, from_state, to_state)
        with self._state_lock:
            self.unsettled.pop(upload_id, None)

    def retry_unsettled(self) -> None:
        with self._state_lock:
            pending = list(self.unsettled.items())
        for upload_id, (from_state, to_state) in pending:
            try:
                self.write_state(self._settle, upload_id, from_state, to_state)
            except Exception:  # noqa: BLE001 - still no room: the next request or round tries again
                return

    def maintain(self) -> None:
        """The API process's periodic round: record what a full disk left unsettled, remake the reserve."""
        self.retry_unsettled()
        disk.restore_reserve(self.settings, self.disk_state())

    # -- acceptance ------------------------------------------------------------------------------
    def accept(
        self,
        key: auth.ApiKey,
        temp: Path,
        size: int,
        *,
        hold: Hold,
        params: SubmissionParams,
        upload_id: str | None = None,
    ) -> dict:
        """Turn a complete, fsynced file into a queued submission (runs in a thread); `hold`, from
        `upload_slot`, is dropped in the same step as the job row is committed.

        On refusal (a `ServiceError`) `temp` is left where it was: the caller decides
        whether the bytes are kept (a resumable upload refused by a quota) or dropped.
        """
        if size == 0:
            raise Invalid("the upload is empty")
        store, settings = self.store, self.settings
        method = display_name(params.method or key.name)
        self._check_quota(key, size, hold, upload_id)
        try:
            suffix = check_container(temp, self.limits).suffix
        except NotASubmissionError as exc:
            raise NotASubmission(public_message(exc, temp)) from exc
        except ParseError as exc:
            raise Invalid(public_message(exc, temp)) from exc
        submission_id = jobs.new_id()
        file_name = submission_id + suffix
        final = settings.submissions_dir / file_name
        # File first, row second: a committed row always has its file on disk.
        os.replace(temp, final)
        jobs.fsync_dir(settings.submissions_dir)
        try:
            with self.holds.gate, store.transaction():
                self._check_quota(key, size, hold, upload_id)  # again, under the write lock
                if not jobs.claim_method(store, params.challenge, method, key.id):
                    raise NotOwner(f"the method name {method!r} was just taken by another key; choose another name")
                jobs.insert_submission(
                    store,
                    submission_id,
                    key.id,
                    dataclasses.replace(params, method=method),
                    file_name=file_name,
                    upload_bytes=size,
                )
                if upload_id is not None:  # same transaction: the upload and its submission agree
                    store.execute("UPDATE uploads SET submission_id = ? WHERE id = ?", (submission_id, upload_id))
                self.holds.release(hold)  # still under the gate, committed on leaving: the job counts itself
        except BaseException:
            os.replace(final, temp)
            raise
        row = jobs.get_submission(store, submission_id)
        if row is None:  # its owner deleted it in the instant since its commit
            raise NotFound(f"submission {submission_id} was deleted")
        return row


def public_message(exc: Exception, path: Path) -> str:
    """An error about an upload as its sender sees it: the file is `submission`, not a server path."""
    return jobs.without_paths(str(exc), [(str(path.resolve()), "submission"), (str(path), "submission")])


def service(request: Request) -> Service:
    """The dependency every route takes."""
    return request.app.state.service


def current_key(
    request: Request, creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]
) -> auth.ApiKey:
    """The dependency of authenticated routes: the caller's key (401 when missing or revoked)."""
    return service(request).key_for(creds, request.client.host if request.client else "")


ServiceDep = Annotated[Service, Depends(service)]
Key = Annotated[auth.ApiKey, Depends(current_key)]
