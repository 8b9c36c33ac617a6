"""The service's state and the rules every route applies: keys, quotas, ownership, acceptance.

One `Service` per API process (`app.state.service`): the settings, the job
store, and the in-memory locks of resumable uploads. Routes reach it through
the `service` dependency and authenticate with `current_key`.
"""
from __future__ import annotations

import asyncio
import os
import re
from pathlib import Path
from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.responses import JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from wosac_eval.metrics.config import PRESET_CHALLENGE, default_config

from . import auth, jobs
from .db import Store
from .models import status_of
from .settings import Settings
from .uploads import check_archive

ID_PATTERN = r"^[0-9a-f]{32}$"

bearer = HTTPBearer(auto_error=False, description="An API key from `wosac-server keys create`.")


class Service:
    """Settings, store and the checks shared by the routes."""

    def __init__(self, settings: Settings):
        self.settings = settings
        settings.ensure_dirs()
        self.store = Store(settings.resolved_db_url)
        self.store.migrate()
        # Bodies of direct uploads cut short by a crash of a previous run: nobody will finish them.
        for orphan in settings.uploads_dir.glob("*.body"):
            orphan.unlink(missing_ok=True)
        self.upload_locks: dict[str, asyncio.Lock] = {}

    # -- what may be asked for ---------------------------------------------------------------
    def config_for(self, challenge: str, config: str | None) -> str:
        """The config a job is scored with: the asked one, or the challenge's current one; 422 when not served."""
        config = default_config(challenge) if config is None else config
        if config not in self.settings.configs:
            raise HTTPException(422, f"unknown config {config!r}; this server scores {self.settings.configs}")
        made_for = PRESET_CHALLENGE.get(config)
        if made_for is not None and made_for.value != challenge:
            raise HTTPException(422, f"config {config!r} is the {made_for.value} challenge's; the {challenge} "
                                f"challenge's is {default_config(challenge)!r}")
        return config

    # -- keys, quotas, ownership ---------------------------------------------------------------
    def key_for(self, creds: HTTPAuthorizationCredentials | None) -> auth.ApiKey:
        if creds is None or creds.scheme.lower() != "bearer":
            raise HTTPException(401, "missing API key: send 'Authorization: Bearer <key>'",
                                headers={"WWW-Authenticate": "Bearer"})
        key = auth.verify_key(self.store, creds.credentials)
        if key is None:
            raise HTTPException(401, "unknown or revoked API key",
                                headers={"WWW-Authenticate": 'Bearer error="invalid_token"'})
        return key

    @staticmethod
    def quota_error(exc: auth.QuotaExceeded) -> HTTPException:
        headers = {"Retry-After": str(exc.retry_after_s)} if exc.retry_after_s else None
        return HTTPException(exc.status, exc.message, headers=headers)

    def own_submission(self, key: auth.ApiKey, submission_id: str) -> dict:
        # 404 (not 403) for another user's id: ids of others are not even confirmed to exist.
        row = jobs.get_submission(self.store, submission_id) if re.match(ID_PATTERN, submission_id) else None
        if row is None or row["key_id"] != key.id:
            raise HTTPException(404, f"no submission {submission_id!r} for this API key")
        return row

    def own_upload(self, key: auth.ApiKey, upload_id: str) -> dict:
        row = jobs.get_upload(self.store, upload_id) if re.match(ID_PATTERN, upload_id) else None
        if row is None or row["key_id"] != key.id:
            raise HTTPException(404, f"no upload {upload_id!r} for this API key")
        return row

    def upload_limit(self, key: auth.ApiKey) -> int:
        return min(self.settings.max_upload_bytes, auth.remaining_daily_bytes(self.store, key))

    def refuse_early(self, key: auth.ApiKey, declared: int | None) -> None:
        """Quota and size checks before a single body byte is read."""
        try:
            auth.check_submission_quota(self.store, key, 0)
        except auth.QuotaExceeded as exc:
            raise self.quota_error(exc)
        limit = self.settings.max_upload_bytes
        if declared is not None and declared > limit:
            raise HTTPException(413, f"the body is {declared} bytes; this server accepts at most {limit} bytes "
                                "(WOSAC_MAX_UPLOAD_BYTES)")
        if declared is not None and declared > self.upload_limit(key):
            raise HTTPException(413, f"the body is {declared} bytes; key {key.name!r} has "
                                f"{self.upload_limit(key)} bytes left of its daily quota")

    def too_large(self, key: auth.ApiKey) -> HTTPException:
        return HTTPException(413, f"the body exceeds the {self.upload_limit(key)} bytes this key may upload now "
                             f"(server limit {self.settings.max_upload_bytes} bytes, WOSAC_MAX_UPLOAD_BYTES)")

    # -- acceptance ------------------------------------------------------------------------------
    def accept(self, key: auth.ApiKey, temp: Path, size: int, *, method: str | None, challenge: str, config: str,
               allow_partial: bool, publish: bool, upload_id: str | None = None) -> dict:
        """Turn a complete, fsynced file into a queued submission (runs in a thread).

        On refusal (HTTPException) `temp` is left where it was: the caller decides
        whether the bytes are kept (a resumable upload refused by a quota) or dropped.
        """
        if size == 0:
            raise HTTPException(422, "the upload is empty")
        suffix = jobs.sniff_suffix(temp)
        problem = check_archive(temp, suffix)
        if problem is not None:
            raise HTTPException(422, problem)
        store, settings = self.store, self.settings
        try:
            auth.check_submission_quota(store, key, size)
        except auth.QuotaExceeded as exc:
            raise self.quota_error(exc)
        submission_id = jobs.new_id()
        file_name = submission_id + suffix
        final = settings.submissions_dir / file_name
        # File first, row second: a committed row always has its file on disk.
        os.replace(temp, final)
        jobs.fsync_dir(settings.submissions_dir)
        try:
            with store.transaction():
                auth.check_submission_quota(store, key, size)  # again, under the write lock
                jobs.insert_submission(store, submission_id=submission_id, key_id=key.id,
                                       method=method or key.name, challenge=challenge, config=config,
                                       allow_partial=allow_partial, published=publish,
                                       file_name=file_name, upload_bytes=size)
                if upload_id is not None:  # same transaction: the upload and its submission agree
                    store.execute("UPDATE uploads SET submission_id = ? WHERE id = ?", (submission_id, upload_id))
        except auth.QuotaExceeded as exc:
            os.replace(final, temp)
            raise self.quota_error(exc)
        except BaseException:
            os.replace(final, temp)
            raise
        return jobs.get_submission(store, submission_id)

    @staticmethod
    def accepted(row: dict) -> JSONResponse:
        body = status_of(row).model_dump()
        return JSONResponse(body, status_code=202, headers={"Location": f"/v1/submissions/{row['id']}"})


def service(request: Request) -> Service:
    """The dependency every route takes."""
    return request.app.state.service


def current_key(request: Request,
                creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> auth.ApiKey:
    """The dependency of authenticated routes: the caller's key (401 when missing or revoked)."""
    return service(request).key_for(creds)


ServiceDep = Annotated[Service, Depends(service)]
Key = Annotated[auth.ApiKey, Depends(current_key)]
