"""The HTTP API (FastAPI): uploads, submission status, results, leaderboard.

Uploads are streamed to a server-named file inside the data dir in chunks
(never read whole into memory), fsynced, renamed, and only then is the job row
committed and `202` answered: an accepted submission survives any crash after
the answer. Large uploads can be resumed (tus-like, see `/v1/uploads`).
Scoring itself happens in worker processes (`worker.py`); this process only
reads and writes the job store.
"""

import asyncio
import csv
import errno
import io
import json
import os
import re
import tarfile
import zlib
from contextlib import asynccontextmanager
from datetime import datetime, timezone
from pathlib import Path, PurePosixPath
from typing import Annotated, Any, Literal

from fastapi import Depends, FastAPI, Header, HTTPException, Path as PathParam, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import BaseModel, Field
from starlette.requests import ClientDisconnect

from . import auth, jobs
from .auth import METHOD_PATTERN
from .db import Store
from .settings import Settings, load_settings

ID_PATTERN = r"^[0-9a-f]{32}$"
MAX_HEADER_INT = 2**62  # fits a BIGINT on every engine
# After refusing an oversized body, read (and drop) this much more so the client,
# still sending, gets to read our 413 instead of a reset connection.
DRAIN_AFTER_REFUSAL = 8 * 1024 * 1024

bearer = HTTPBearer(auto_error=False, description="An API key from `wosac-eval keys create`.")


# -- response models (they make the OpenAPI schema) --------------------------------------
class Progress(BaseModel):
    scenarios_done: int
    scenarios_total: int | None = Field(None, description="Known once validation has read the submission.")


class SubmissionStatus(BaseModel):
    id: str
    state: Literal["queued", "validating", "scoring", "done", "failed"]
    method: str
    config: str
    published: bool
    allow_partial: bool
    upload_bytes: int
    progress: Progress
    attempts: int = Field(description="Scoring attempts started (a worker that died counts one).")
    created_at: str
    updated_at: str
    started_at: str | None = None
    finished_at: str | None = None
    error: str | None = Field(None, description="Why the submission failed.")
    validation_report: dict[str, Any] | None = Field(
        None, description="The validator's report when the submission was judged invalid.")
    realism_meta_metric: float | None = None
    results_url: str | None = None


class SubmissionList(BaseModel):
    submissions: list[SubmissionStatus]


class LeaderboardEntry(BaseModel):
    rank: int
    method: str
    submission_id: str
    realism_meta_metric: float
    buckets: dict[str, Any]
    finished_at: str


class Leaderboard(BaseModel):
    config: str
    entries: list[LeaderboardEntry]


class UploadStatus(BaseModel):
    upload_id: str
    offset: int = Field(description="Bytes received and stored so far; the next PATCH starts here.")
    length: int | None = Field(None, description="Total size declared with Upload-Length, if any.")
    submission_id: str | None = Field(None, description="Set once the upload was completed.")


class Health(BaseModel):
    status: str
    database: str
    scenarios: int


def iso(t: float | None) -> str | None:
    if t is None:
        return None
    return datetime.fromtimestamp(t, tz=timezone.utc).isoformat(timespec="milliseconds")


def status_of(row: dict) -> SubmissionStatus:
    report = json.loads(row["report"]) if row.get("report") else None
    return SubmissionStatus(
        id=row["id"], state=row["state"], method=row["method"], config=row["config"],
        published=bool(row["published"]), allow_partial=bool(row["allow_partial"]),
        upload_bytes=row["upload_bytes"],
        progress=Progress(scenarios_done=row["scenarios_done"], scenarios_total=row["scenarios_total"]),
        attempts=row["attempts"], created_at=iso(row["created_at"]), updated_at=iso(row["updated_at"]),
        started_at=iso(row["started_at"]), finished_at=iso(row["finished_at"]), error=row["error"],
        validation_report=report, realism_meta_metric=row["realism_meta_metric"],
        results_url=f"/v1/submissions/{row['id']}/results" if row["state"] == "done" else None,
    )


# -- upload mechanics ---------------------------------------------------------------------
class BodyTooLarge(Exception):
    pass


def disk_full(exc: OSError) -> HTTPException:
    return HTTPException(507, f"the server could not store the upload ({os.strerror(exc.errno or 0)}); "
                         "retry later (resumable uploads keep what was stored)")


async def stream_body_to(request: Request, path: Path, limit: int, mode: str = "wb") -> tuple[int, bool]:
    """Append the request body to `path` chunk by chunk, at most `limit` bytes.

    Returns (bytes written, client disconnected). Raises BodyTooLarge past the
    limit (after draining a little so the client can read the answer). The file
    is fsynced before returning, so the bytes counted are on disk.
    """
    written, disconnected = 0, False
    with open(path, mode) as f:
        try:
            stream = request.stream()
            async for chunk in stream:
                if written + len(chunk) > limit:
                    drained = 0
                    async for extra in stream:
                        drained += len(extra)
                        if drained > DRAIN_AFTER_REFUSAL:
                            break
                    raise BodyTooLarge()
                f.write(chunk)
                written += len(chunk)
        except ClientDisconnect:
            disconnected = True
        except OSError as exc:
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                raise disk_full(exc)
            raise
        f.flush()
        await run_in_threadpool(os.fsync, f.fileno())
    return written, disconnected


def check_archive(path: Path, suffix: str) -> str | None:
    """A reason to refuse a tar upload at once (unreadable, unsafe member names), or None.

    Members are never extracted to disk; the names are still refused so that no
    tool a user may point at the stored archive can write outside its folder.
    """
    if suffix == ".binproto":
        return None
    try:
        with tarfile.open(path, mode="r|*") as tar:
            count = 0
            for member in tar:
                count += 1
                name = member.name
                parts = PurePosixPath(name).parts
                if name.startswith("/") or "\\" in name or ".." in parts or "\x00" in name:
                    return f"archive member {name!r} has an unsafe path (absolute or with '..')"
                if not (member.isfile() or member.isdir()):
                    return f"archive member {name!r} is a link or device, not a regular file"
            if count == 0:
                return "the archive holds no files"
    except (tarfile.TarError, zlib.error, EOFError, OSError) as exc:
        return f"not a readable {suffix} archive: {exc}"
    return None


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or load_settings()
    settings.ensure_dirs()
    store = Store(settings.resolved_db_url)
    store.migrate()
    # Bodies of direct uploads cut short by a crash of a previous run: nobody will finish them.
    for orphan in settings.uploads_dir.glob("*.body"):
        orphan.unlink(missing_ok=True)
    upload_locks: dict[str, asyncio.Lock] = {}

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        yield
        store.close()

    app = FastAPI(
        title="wosac-eval scoring service",
        version="1",
        description="Upload a WOSAC submission, follow its scoring, fetch exact results.",
        lifespan=lifespan,
        # The interactive docs pages load their scripts from a CDN; the schema alone is served.
        docs_url=None,
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.store = store

    def current_key(creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> auth.ApiKey:
        if creds is None or creds.scheme.lower() != "bearer":
            raise HTTPException(401, "missing API key: send 'Authorization: Bearer <key>'",
                                headers={"WWW-Authenticate": "Bearer"})
        key = auth.verify_key(store, creds.credentials)
        if key is None:
            raise HTTPException(401, "unknown or revoked API key",
                                headers={"WWW-Authenticate": 'Bearer error="invalid_token"'})
        return key

    Key = Annotated[auth.ApiKey, Depends(current_key)]
    ConfigQ = Annotated[str, Query(description="Metric config (challenge year).")]
    MethodQ = Annotated[str | None, Query(pattern=METHOD_PATTERN,
                                          description="Method name on the leaderboard (default: key name).")]
    PublishQ = Annotated[bool, Query(description="Show the result on the public leaderboard.")]
    PartialQ = Annotated[bool, Query(description="Score only the scenarios the submission covers.")]
    SubmissionId = Annotated[str, PathParam(description="Submission id (32 hex digits).")]
    UploadId = Annotated[str, PathParam(description="Upload id (32 hex digits).")]

    def check_config(config: str) -> str:
        if config not in settings.configs:
            raise HTTPException(422, f"unknown config {config!r}; this server scores {settings.configs}")
        return config

    def quota_error(exc: auth.QuotaExceeded) -> HTTPException:
        headers = {"Retry-After": str(exc.retry_after_s)} if exc.retry_after_s else None
        return HTTPException(exc.status, exc.message, headers=headers)

    def own_submission(key: auth.ApiKey, submission_id: str) -> dict:
        # 404 (not 403) for another user's id: ids of others are not even confirmed to exist.
        row = jobs.get_submission(store, submission_id) if re.match(ID_PATTERN, submission_id) else None
        if row is None or row["key_id"] != key.id:
            raise HTTPException(404, f"no submission {submission_id!r} for this API key")
        return row

    def own_upload(key: auth.ApiKey, upload_id: str) -> dict:
        row = jobs.get_upload(store, upload_id) if re.match(ID_PATTERN, upload_id) else None
        if row is None or row["key_id"] != key.id:
            raise HTTPException(404, f"no upload {upload_id!r} for this API key")
        return row

    def upload_limit(key: auth.ApiKey) -> int:
        return min(settings.max_upload_bytes, auth.remaining_daily_bytes(store, key))

    def refuse_early(key: auth.ApiKey, declared: int | None) -> None:
        """Quota and size checks before a single body byte is read."""
        try:
            auth.check_submission_quota(store, key, 0)
        except auth.QuotaExceeded as exc:
            raise quota_error(exc)
        if declared is not None and declared > settings.max_upload_bytes:
            raise HTTPException(413, f"the body is {declared} bytes; this server accepts at most "
                                f"{settings.max_upload_bytes} bytes (WOSAC_MAX_UPLOAD_BYTES)")
        if declared is not None and declared > upload_limit(key):
            raise HTTPException(413, f"the body is {declared} bytes; key {key.name!r} has "
                                f"{upload_limit(key)} bytes left of its daily quota")

    def too_large(key: auth.ApiKey) -> HTTPException:
        return HTTPException(413, f"the body exceeds the {upload_limit(key)} bytes this key may upload now "
                             f"(server limit {settings.max_upload_bytes} bytes, WOSAC_MAX_UPLOAD_BYTES)")

    def accept(key: auth.ApiKey, temp: Path, size: int, *, method: str | None, config: str,
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
        try:
            auth.check_submission_quota(store, key, size)
        except auth.QuotaExceeded as exc:
            raise quota_error(exc)
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
                                       method=method or key.name, config=config,
                                       allow_partial=allow_partial, published=publish,
                                       file_name=file_name, upload_bytes=size)
                if upload_id is not None:  # same transaction: the upload and its submission agree
                    store.execute("UPDATE uploads SET submission_id = ? WHERE id = ?", (submission_id, upload_id))
        except auth.QuotaExceeded as exc:
            os.replace(final, temp)
            raise quota_error(exc)
        except BaseException:
            os.replace(final, temp)
            raise
        return jobs.get_submission(store, submission_id)

    def accepted(row: dict) -> JSONResponse:
        body = status_of(row).model_dump()
        return JSONResponse(body, status_code=202, headers={"Location": f"/v1/submissions/{row['id']}"})

    # -- routes ------------------------------------------------------------------------------
    @app.get("/healthz", response_model=Health, tags=["service"], operation_id="health")
    def healthz():
        try:
            store.ping()
        except Exception as exc:  # the answer must say the DB is down, not crash
            return JSONResponse({"status": "error", "database": f"unreachable: {exc}",
                                 "scenarios": len(settings.scenario_paths())}, status_code=503)
        return Health(status="ok", database="ok", scenarios=len(settings.scenario_paths()))

    # OpenAPI links: which operation can follow which, with the id taken from the answer.
    submission_links = {"links": {
        "status": {"operationId": "getSubmission", "parameters": {"submission_id": "$response.body#/id"}},
        "results": {"operationId": "getResults", "parameters": {"submission_id": "$response.body#/id"}}}}
    upload_links = {"links": {
        op: {"operationId": op, "parameters": {"upload_id": "$response.body#/upload_id"}}
        for op in ("getUpload", "headUpload", "patchUpload", "completeUpload", "deleteUpload")}}

    octet_body = {"requestBody": {"required": True, "content": {
        "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}}}

    @app.post("/v1/submissions", status_code=202, response_model=SubmissionStatus, tags=["submissions"],
              openapi_extra=octet_body, operation_id="createSubmission",
              responses={202: submission_links, 413: {"description": "Body too large"},
                         429: {"description": "Quota exceeded"},
                         422: {"description": "Not a readable submission container"}})
    async def create_submission(request: Request, key: Key, config: ConfigQ = "2025", method: MethodQ = None,
                                publish: PublishQ = False, allow_partial: PartialQ = False,
                                content_length: Annotated[int | None, Header(ge=0, le=MAX_HEADER_INT)] = None):
        """Upload a whole submission (`.tar.gz`, `.tar` or one `.binproto`) as the raw request body."""
        check_config(config)
        await run_in_threadpool(refuse_early, key, content_length)
        limit = await run_in_threadpool(upload_limit, key)
        temp = settings.uploads_dir / f"{jobs.new_id()}.body"
        try:
            size, disconnected = await stream_body_to(request, temp, limit)
        except BodyTooLarge:
            temp.unlink(missing_ok=True)
            raise too_large(key)
        except BaseException:
            temp.unlink(missing_ok=True)
            raise
        if disconnected or (content_length is not None and size != content_length):
            temp.unlink(missing_ok=True)
            raise HTTPException(400, f"the body ended after {size} bytes (client disconnected or sent "
                                "less than Content-Length); use /v1/uploads to resume large uploads")
        try:
            row = await run_in_threadpool(accept, key, temp, size, method=method, config=config,
                                          allow_partial=allow_partial, publish=publish)
        finally:
            temp.unlink(missing_ok=True)  # gone already when accepted (renamed)
        return accepted(row)

    @app.get("/v1/submissions", response_model=SubmissionList, tags=["submissions"],
             operation_id="listSubmissions")
    def list_submissions(key: Key, limit: Annotated[int, Query(ge=1, le=1000)] = 100):
        """Your submissions, newest first."""
        return SubmissionList(submissions=[status_of(r) for r in jobs.list_submissions(store, key.id, limit)])

    @app.get("/v1/submissions/{submission_id}", response_model=SubmissionStatus, tags=["submissions"],
             operation_id="getSubmission")
    def get_submission(key: Key, submission_id: SubmissionId):
        return status_of(own_submission(key, submission_id))

    @app.get("/v1/submissions/{submission_id}/results", tags=["submissions"], operation_id="getResults",
             responses={200: {"content": {"application/json": {}, "text/csv": {}}},
                        409: {"description": "Not scored (yet)"}})
    def get_results(key: Key, submission_id: SubmissionId,
                    format: Annotated[Literal["json", "csv"], Query()] = "json"):
        """The result JSON, exactly as `wosac-eval score` writes it (or per-scenario CSV)."""
        row = own_submission(key, submission_id)
        if row["state"] != "done":
            detail = f"submission {submission_id} is {row['state']}; results exist once it is done"
            if row["state"] == "failed":
                detail = f"submission {submission_id} failed: {row['error']}"
            raise HTTPException(409, detail)
        path = settings.results_dir / f"{submission_id}.json"
        if format == "json":
            return FileResponse(path, media_type="application/json")
        with open(path) as f:
            return PlainTextResponse(result_csv(json.load(f)), media_type="text/csv")

    @app.get("/v1/leaderboard", response_model=Leaderboard, tags=["leaderboard"], operation_id="leaderboard")
    def get_leaderboard(config: ConfigQ = "2025"):
        """Best published result per method (public, no key needed)."""
        check_config(config)
        entries = [LeaderboardEntry(**{**e, "finished_at": iso(e["finished_at"])})
                   for e in jobs.leaderboard(store, config)]
        return Leaderboard(config=config, entries=entries)

    # -- resumable uploads (tus-like) --------------------------------------------------------
    @app.post("/v1/uploads", status_code=201, response_model=UploadStatus, tags=["uploads"],
              operation_id="createUpload",
              responses={201: upload_links, 413: {"description": "Declared length too large"},
                         429: {"description": "Quota"}})
    def create_upload(key: Key, config: ConfigQ = "2025", method: MethodQ = None, publish: PublishQ = False,
                      allow_partial: PartialQ = False,
                      upload_length: Annotated[int | None, Header(ge=1, le=MAX_HEADER_INT)] = None):
        """Start a resumable upload; send the bytes with PATCH, then POST .../complete."""
        check_config(config)
        refuse_early(key, upload_length)
        upload_id = jobs.new_id()
        (settings.uploads_dir / f"{upload_id}.part").touch()
        jobs.insert_upload(store, upload_id=upload_id, key_id=key.id, method=method or key.name,
                           config=config, allow_partial=allow_partial, published=publish,
                           declared_length=upload_length)
        body = UploadStatus(upload_id=upload_id, offset=0, length=upload_length).model_dump()
        return JSONResponse(body, status_code=201, headers={
            "Location": f"/v1/uploads/{upload_id}", "Upload-Offset": "0"})

    def check_part(part: Path, row: dict) -> None:
        # Never let truncate() pad a lost file with zeros: refuse instead.
        if not part.exists() or part.stat().st_size < row["received_bytes"]:
            raise HTTPException(410, "the stored bytes of this upload are gone; start a new upload")

    def upload_headers(row: dict) -> dict[str, str]:
        headers = {"Upload-Offset": str(row["received_bytes"]), "Cache-Control": "no-store"}
        if row["declared_length"] is not None:
            headers["Upload-Length"] = str(row["declared_length"])
        return headers

    @app.head("/v1/uploads/{upload_id}", tags=["uploads"], operation_id="headUpload")
    def head_upload(key: Key, upload_id: UploadId):
        """The current offset, in the `Upload-Offset` header."""
        return Response(status_code=200, headers=upload_headers(own_upload(key, upload_id)))

    @app.get("/v1/uploads/{upload_id}", response_model=UploadStatus, tags=["uploads"], operation_id="getUpload")
    def get_upload(key: Key, upload_id: UploadId):
        row = own_upload(key, upload_id)
        return JSONResponse(UploadStatus(upload_id=row["id"], offset=row["received_bytes"],
                                         length=row["declared_length"],
                                         submission_id=row["submission_id"]).model_dump(),
                            headers=upload_headers(row))

    @app.patch("/v1/uploads/{upload_id}", status_code=204, tags=["uploads"], openapi_extra=octet_body,
               operation_id="patchUpload",
               responses={409: {"description": "Upload-Offset does not match the stored offset"},
                          413: {"description": "Chunk would exceed the size limit"}})
    async def patch_upload(request: Request, key: Key, upload_id: UploadId,
                           upload_offset: Annotated[int, Header(ge=0, le=MAX_HEADER_INT)]):
        """Append the body at `Upload-Offset`; answers the new offset in `Upload-Offset`."""
        row = await run_in_threadpool(own_upload, key, upload_id)
        lock = upload_locks.setdefault(upload_id, asyncio.Lock())
        if lock.locked():
            raise HTTPException(409, "another PATCH for this upload is in progress",
                                headers=upload_headers(row))
        async with lock:
            row = await run_in_threadpool(jobs.get_upload, store, upload_id)
            if row["submission_id"] is not None:
                raise HTTPException(409, "this upload is already complete")
            offset = row["received_bytes"]
            if upload_offset != offset:
                raise HTTPException(409, f"Upload-Offset {upload_offset} does not match the stored "
                                    f"offset {offset}; HEAD the upload and resume from there",
                                    headers=upload_headers(row))
            part = settings.uploads_dir / f"{upload_id}.part"
            check_part(part, row)
            # Bytes past the committed offset (a crash mid-PATCH) are not trusted: cut them.
            with open(part, "ab") as f:
                f.truncate(offset)
            limit = await run_in_threadpool(upload_limit, key)
            limit = min(limit, settings.max_upload_bytes) - offset
            if row["declared_length"] is not None:
                limit = min(limit, row["declared_length"] - offset)
            try:
                written, _ = await stream_body_to(request, part, max(0, limit), mode="ab")
            except BodyTooLarge:
                with open(part, "ab") as f:
                    f.truncate(offset)
                raise HTTPException(413, f"this chunk would take the upload past its limit "
                                    f"({offset + max(0, limit)} bytes: declared Upload-Length, the "
                                    "server's WOSAC_MAX_UPLOAD_BYTES or the key's daily quota)",
                                    headers=upload_headers(row))
            await run_in_threadpool(jobs.set_upload_offset, store, upload_id, offset + written)
        upload_locks.pop(upload_id, None)
        return Response(status_code=204, headers={"Upload-Offset": str(offset + written)})

    @app.post("/v1/uploads/{upload_id}/complete", status_code=202, response_model=SubmissionStatus,
              tags=["uploads"], operation_id="completeUpload",
              responses={202: submission_links, 409: {"description": "Upload incomplete"}})
    async def complete_upload(key: Key, upload_id: UploadId):
        """Turn the uploaded bytes into a queued submission (idempotent)."""
        row = await run_in_threadpool(own_upload, key, upload_id)
        lock = upload_locks.setdefault(upload_id, asyncio.Lock())
        async with lock:
            row = await run_in_threadpool(jobs.get_upload, store, upload_id)
            if row["submission_id"] is not None:
                return accepted(await run_in_threadpool(jobs.get_submission, store, row["submission_id"]))
            if row["declared_length"] is not None and row["received_bytes"] != row["declared_length"]:
                raise HTTPException(409, f"received {row['received_bytes']} of the "
                                    f"{row['declared_length']} declared bytes; PATCH the rest first",
                                    headers=upload_headers(row))
            part = settings.uploads_dir / f"{upload_id}.part"
            check_part(part, row)
            with open(part, "ab") as f:
                f.truncate(row["received_bytes"])  # only the committed bytes count
            try:
                sub = await run_in_threadpool(
                    accept, key, part, row["received_bytes"], method=row["method"], config=row["config"],
                    allow_partial=bool(row["allow_partial"]), publish=bool(row["published"]),
                    upload_id=upload_id)
            except HTTPException as exc:
                if exc.status_code != 429:  # a quota may free up: keep the bytes; the rest is final
                    part.unlink(missing_ok=True)
                    await run_in_threadpool(store.execute, "DELETE FROM uploads WHERE id = ?", (upload_id,))
                raise
        upload_locks.pop(upload_id, None)
        return accepted(sub)

    @app.delete("/v1/uploads/{upload_id}", status_code=204, tags=["uploads"], operation_id="deleteUpload")
    def delete_upload(key: Key, upload_id: UploadId):
        """Abandon an unfinished upload and free its disk space."""
        row = own_upload(key, upload_id)
        if row["submission_id"] is not None:
            raise HTTPException(409, "this upload was completed; it is a submission now")
        (settings.uploads_dir / f"{upload_id}.part").unlink(missing_ok=True)
        store.execute("DELETE FROM uploads WHERE id = ?", (upload_id,))
        return Response(status_code=204)

    from .web import install_pages

    install_pages(app, store, settings)
    return app


def result_csv(result: dict) -> str:
    """Per-scenario rows of a result JSON: `scenario_id`, then every metric field."""
    scenarios = result.get("scenarios") or []
    fields: list[str] = []
    for s in scenarios:
        for k in s:
            if k not in fields and not isinstance(s[k], (dict, list)):
                fields.append(k)
    if "scenario_id" in fields:
        fields.remove("scenario_id")
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["scenario_id", *fields])
    for s in scenarios:
        writer.writerow([s.get("scenario_id"), *(repr(s[k]) if isinstance(s.get(k), float) else s.get(k, "")
                                                 for k in fields)])
    return out.getvalue()
