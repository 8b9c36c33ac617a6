"""`/v1/uploads`: resumable uploads (tus-like) for large submissions.

Create an upload, `PATCH` chunks at the offset the server holds, ask `HEAD`
for that offset after a dropped connection, then `complete` it into a queued
submission. An upload's state lives in the database (open, writing, completing,
deleting, complete): every PATCH, complete and DELETE first moves it out of `open` with a
compare-and-set, so at most one of them works on an upload at a time, and moves it on when it
ends, even on a full disk (`Service.settle_upload`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Header, HTTPException, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from .. import disk, jobs
from ..models import SubmissionStatus, UploadStatus
from ..service import Key, ServiceDep
from ..uploads import BodyTooLarge, stream_body_to
from .params import (
    MAX_HEADER_INT,
    OCTET_BODY,
    SUBMISSION_LINKS,
    UPLOAD_LINKS,
    ChallengeQ,
    ConfigQ,
    MethodQ,
    PartialQ,
    PublishQ,
    UploadId,
)

router = APIRouter(prefix="/v1/uploads", tags=["uploads"])
DISK_FULL = {"description": "The server's disk is full or past its floor; retry after Retry-After seconds"}


def _check_part(part: Path, row: dict) -> None:
    # Never let truncate() pad a lost file with zeros: refuse instead.
    if not part.exists() or part.stat().st_size < row["received_bytes"]:
        raise HTTPException(410, "the stored bytes of this upload are gone; start a new upload")


def _headers(row: dict) -> dict[str, str]:
    headers = {"Upload-Offset": str(row["received_bytes"]), "Cache-Control": "no-store"}
    if row["declared_length"] is not None:
        headers["Upload-Length"] = str(row["declared_length"])
    return headers


@router.post(
    "",
    status_code=201,
    response_model=UploadStatus,
    operation_id="createUpload",
    responses={
        201: UPLOAD_LINKS,
        413: {"description": "Declared length too large"},
        507: DISK_FULL,
        429: {"description": "Quota, or too many unfinished uploads"},
        403: {"description": "Method name owned by another key"},
    },
)
def create_upload(
    svc: ServiceDep,
    key: Key,
    challenge: ChallengeQ = "sim_agents",
    config: ConfigQ = None,
    method: MethodQ = None,
    publish: PublishQ = False,
    allow_partial: PartialQ = False,
    upload_length: Annotated[int | None, Header(ge=1, le=MAX_HEADER_INT)] = None,
):
    """Start a resumable upload; send the bytes with PATCH, then POST .../complete."""
    config = svc.config_for(challenge, config)
    method = svc.check_method(key, challenge, method or key.name)
    svc.refuse_early(key, upload_length)
    upload_id = jobs.new_id()
    part = svc.settings.uploads_dir / f"{upload_id}.part"
    declared = upload_length or 0
    # The space check and the promise (the row, whose declared bytes count as reserved) as one step.
    with svc.space_gate:
        svc.need_space(declared + disk.job_need_bytes(declared))
        part.touch()
        try:
            with svc.store.transaction():  # the count and the insert under one write lock
                held = jobs.open_uploads(svc.store, key.id)
                if held >= svc.settings.max_open_uploads:
                    raise HTTPException(
                        429,
                        f"key {key.name!r} has {held} unfinished uploads, its limit "
                        f"(WOSAC_MAX_OPEN_UPLOADS); complete or DELETE one first",
                    )
                jobs.insert_upload(
                    svc.store,
                    upload_id=upload_id,
                    key_id=key.id,
                    method=method or key.name,
                    challenge=challenge,
                    config=config,
                    allow_partial=allow_partial,
                    published=publish,
                    declared_length=upload_length,
                )
        except BaseException:
            part.unlink(missing_ok=True)
            raise
    body = UploadStatus(upload_id=upload_id, offset=0, length=upload_length).model_dump()
    return JSONResponse(body, status_code=201, headers={"Location": f"/v1/uploads/{upload_id}", "Upload-Offset": "0"})


@router.head("/{upload_id}", operation_id="headUpload")
def head_upload(svc: ServiceDep, key: Key, upload_id: UploadId):
    """The current offset, in the `Upload-Offset` header."""
    return Response(status_code=200, headers=_headers(svc.own_upload(key, upload_id)))


@router.get("/{upload_id}", response_model=UploadStatus, operation_id="getUpload")
def get_upload(svc: ServiceDep, key: Key, upload_id: UploadId):
    row = svc.own_upload(key, upload_id)
    return JSONResponse(
        UploadStatus(
            upload_id=row["id"],
            offset=row["received_bytes"],
            length=row["declared_length"],
            submission_id=row["submission_id"],
        ).model_dump(),
        headers=_headers(row),
    )


def _busy(row: dict | None) -> HTTPException:
    """Why an upload cannot take this request now (its state is not `open`)."""
    if row is None or row["state"] == "deleting":
        return HTTPException(404, "this upload is gone (deleted, expired, or refused when completed)")
    if row["submission_id"] is not None:
        return HTTPException(409, "this upload is already complete", headers=_headers(row))
    doing = {"writing": "a PATCH", "completing": "a complete"}.get(row["state"], row["state"])
    return HTTPException(409, f"{doing} of this upload is in progress; retry when it is done", headers=_headers(row))


@router.patch(
    "/{upload_id}",
    status_code=204,
    openapi_extra=OCTET_BODY,
    operation_id="patchUpload",
    responses={
        409: {"description": "Upload-Offset does not match, or another request is at work"},
        413: {"description": "Chunk would exceed the size limit"},
        507: DISK_FULL,
    },
)
async def patch_upload(
    request: Request,
    svc: ServiceDep,
    key: Key,
    upload_id: UploadId,
    upload_offset: Annotated[int, Header(ge=0, le=MAX_HEADER_INT)],
    content_length: Annotated[int | None, Header(ge=0, le=MAX_HEADER_INT)] = None,
):
    """Append the body at `Upload-Offset`; answers the new offset in `Upload-Offset`."""
    known = await run_in_threadpool(svc.own_upload, key, upload_id)
    # A declared upload's bytes are promised (reserved) already; an undeclared one's chunk is promised here.
    await run_in_threadpool(svc.need_space, 0 if known["declared_length"] is not None else content_length or 0)
    # open -> writing, atomically: a PATCH never overlaps another PATCH, a complete or a DELETE.
    if not await run_in_threadpool(jobs.move_upload, svc.store, upload_id, "open", "writing"):
        raise _busy(await run_in_threadpool(jobs.get_upload, svc.store, upload_id))
    written = 0
    try:
        row = await run_in_threadpool(jobs.held_upload, svc.store, upload_id)
        offset = row["received_bytes"]
        if upload_offset != offset:
            raise HTTPException(
                409,
                f"Upload-Offset {upload_offset} does not match the stored offset {offset}; "
                "HEAD the upload and resume from there",
                headers=_headers(row),
            )
        part = svc.settings.uploads_dir / f"{upload_id}.part"
        _check_part(part, row)
        # Bytes past the committed offset (a crash mid-PATCH) are not trusted: cut them.
        with open(part, "ab") as f:
            f.truncate(offset)
        limit = await run_in_threadpool(svc.upload_limit, key, upload_id) - offset
        if row["declared_length"] is not None:
            limit = min(limit, row["declared_length"] - offset)
        try:
            written, _ = await stream_body_to(request, part, max(0, limit), mode="ab")
            await run_in_threadpool(jobs.set_upload_offset, svc.store, upload_id, offset + written)
        except BodyTooLarge:
            _cut(part, offset)
            raise HTTPException(
                413,
                f"this chunk would take the upload past its limit ({offset + max(0, limit)} "
                "bytes: declared Upload-Length, the server's WOSAC_MAX_UPLOAD_BYTES or the key's "
                "daily quota)",
                headers=_headers(row),
            ) from None
        except BaseException:
            # Bytes past the committed offset are cut at once: on a full disk their space lets the state
            # below be recorded.
            _cut(part, offset)
            raise
    finally:
        # Never left `writing`: settle_upload frees the disk reserve, or retries later, when it cannot write.
        await run_in_threadpool(svc.settle_upload, upload_id, "writing", "open")
    return Response(status_code=204, headers={"Upload-Offset": str(offset + written)})


@router.post(
    "/{upload_id}/complete",
    status_code=202,
    response_model=SubmissionStatus,
    operation_id="completeUpload",
    responses={202: SUBMISSION_LINKS, 409: {"description": "Upload incomplete, or another request at work"}},
)
async def complete_upload(svc: ServiceDep, key: Key, upload_id: UploadId):
    """Turn the uploaded bytes into a queued submission (idempotent)."""
    await run_in_threadpool(svc.own_upload, key, upload_id)
    if not await run_in_threadpool(jobs.move_upload, svc.store, upload_id, "open", "completing"):
        row = await run_in_threadpool(jobs.get_upload, svc.store, upload_id)
        if row is not None and row["submission_id"] is not None:  # completed before: the same answer again
            done = await run_in_threadpool(jobs.get_submission, svc.store, row["submission_id"])
            if done is None:
                raise HTTPException(404, "this upload was completed; its submission was deleted since")
            return svc.accepted(done)
        raise _busy(row)
    outcome = "open"  # what the upload becomes when this request ends
    try:
        row = await run_in_threadpool(jobs.held_upload, svc.store, upload_id)
        if row["declared_length"] is not None and row["received_bytes"] != row["declared_length"]:
            raise HTTPException(
                409,
                f"received {row['received_bytes']} of the {row['declared_length']} declared "
                "bytes; PATCH the rest first",
                headers=_headers(row),
            )
        part = svc.settings.uploads_dir / f"{upload_id}.part"
        _check_part(part, row)
        with open(part, "ab") as f:
            f.truncate(row["received_bytes"])  # only the committed bytes count
        async with svc.upload_slot(key) as hold, svc.check_slots:
            try:
                sub = await run_in_threadpool(
                    svc.accept,
                    key,
                    part,
                    row["received_bytes"],
                    hold=hold,
                    method=row["method"],
                    challenge=row["challenge"],
                    config=row["config"],
                    allow_partial=bool(row["allow_partial"]),
                    publish=bool(row["published"]),
                    upload_id=upload_id,
                )
            except HTTPException as exc:
                if exc.status_code not in (429, 403):  # a quota may free up, a name be chosen: keep the bytes
                    outcome = "refused"
                    part.unlink(missing_ok=True)
                raise
        outcome = "complete"
    finally:
        # "refused": the row goes too. Never left `completing` (see patch_upload).
        await run_in_threadpool(svc.settle_upload, upload_id, "completing", None if outcome == "refused" else outcome)
    return svc.accepted(sub)


@router.delete("/{upload_id}", status_code=204, operation_id="deleteUpload")
def delete_upload(svc: ServiceDep, key: Key, upload_id: UploadId):
    """Abandon an unfinished upload and free its disk space."""
    row = svc.own_upload(key, upload_id)
    if row["submission_id"] is not None:
        raise HTTPException(409, "this upload was completed; it is a submission now")
    if not svc.write_state(jobs.move_upload, svc.store, upload_id, "open", "deleting"):
        raise _busy(jobs.get_upload(svc.store, upload_id))
    # The file first: its space is free even when the database cannot drop the row yet (retried later; a
    # `deleting` upload is gone to every request meanwhile).
    (svc.settings.uploads_dir / f"{upload_id}.part").unlink(missing_ok=True)
    svc.settle_upload(upload_id, "deleting", None)
    return Response(status_code=204)


def _cut(part: Path, offset: int) -> None:
    """Drop a part file's bytes past `offset` (the committed ones); shrinking needs no space."""
    try:
        with open(part, "ab") as f:
            f.truncate(offset)
    except FileNotFoundError:
        pass
