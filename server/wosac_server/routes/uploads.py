"""`/v1/uploads`: resumable uploads (tus-like) for large submissions.

Create an upload, `PATCH` chunks at the offset the server holds, ask `HEAD`
for that offset after a dropped connection, then `complete` it into a queued
submission. Each upload's chunks are serialised by a lock of this process.
"""
from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Header, HTTPException, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from .. import jobs
from ..models import SubmissionStatus, UploadStatus
from ..service import Key, ServiceDep
from ..uploads import BodyTooLarge, stream_body_to
from .params import (MAX_HEADER_INT, OCTET_BODY, SUBMISSION_LINKS, UPLOAD_LINKS, ChallengeQ, ConfigQ, MethodQ,
                     PartialQ, PublishQ, UploadId)

router = APIRouter(prefix="/v1/uploads", tags=["uploads"])


def _check_part(part: Path, row: dict) -> None:
    # Never let truncate() pad a lost file with zeros: refuse instead.
    if not part.exists() or part.stat().st_size < row["received_bytes"]:
        raise HTTPException(410, "the stored bytes of this upload are gone; start a new upload")


def _headers(row: dict) -> dict[str, str]:
    headers = {"Upload-Offset": str(row["received_bytes"]), "Cache-Control": "no-store"}
    if row["declared_length"] is not None:
        headers["Upload-Length"] = str(row["declared_length"])
    return headers


@router.post("", status_code=201, response_model=UploadStatus, operation_id="createUpload",
             responses={201: UPLOAD_LINKS, 413: {"description": "Declared length too large"},
                        429: {"description": "Quota"}})
def create_upload(svc: ServiceDep, key: Key, challenge: ChallengeQ = "sim_agents", config: ConfigQ = None,
                  method: MethodQ = None, publish: PublishQ = False, allow_partial: PartialQ = False,
                  upload_length: Annotated[int | None, Header(ge=1, le=MAX_HEADER_INT)] = None):
    """Start a resumable upload; send the bytes with PATCH, then POST .../complete."""
    config = svc.config_for(challenge, config)
    svc.refuse_early(key, upload_length)
    upload_id = jobs.new_id()
    (svc.settings.uploads_dir / f"{upload_id}.part").touch()
    jobs.insert_upload(svc.store, upload_id=upload_id, key_id=key.id, method=method or key.name,
                       challenge=challenge, config=config, allow_partial=allow_partial, published=publish,
                       declared_length=upload_length)
    body = UploadStatus(upload_id=upload_id, offset=0, length=upload_length).model_dump()
    return JSONResponse(body, status_code=201, headers={"Location": f"/v1/uploads/{upload_id}", "Upload-Offset": "0"})


@router.head("/{upload_id}", operation_id="headUpload")
def head_upload(svc: ServiceDep, key: Key, upload_id: UploadId):
    """The current offset, in the `Upload-Offset` header."""
    return Response(status_code=200, headers=_headers(svc.own_upload(key, upload_id)))


@router.get("/{upload_id}", response_model=UploadStatus, operation_id="getUpload")
def get_upload(svc: ServiceDep, key: Key, upload_id: UploadId):
    row = svc.own_upload(key, upload_id)
    return JSONResponse(UploadStatus(upload_id=row["id"], offset=row["received_bytes"], length=row["declared_length"],
                                     submission_id=row["submission_id"]).model_dump(), headers=_headers(row))


@router.patch("/{upload_id}", status_code=204, openapi_extra=OCTET_BODY, operation_id="patchUpload",
              responses={409: {"description": "Upload-Offset does not match the stored offset"},
                         413: {"description": "Chunk would exceed the size limit"}})
async def patch_upload(request: Request, svc: ServiceDep, key: Key, upload_id: UploadId,
                       upload_offset: Annotated[int, Header(ge=0, le=MAX_HEADER_INT)]):
    """Append the body at `Upload-Offset`; answers the new offset in `Upload-Offset`."""
    row = await run_in_threadpool(svc.own_upload, key, upload_id)
    lock = svc.upload_locks.setdefault(upload_id, asyncio.Lock())
    if lock.locked():
        raise HTTPException(409, "another PATCH for this upload is in progress", headers=_headers(row))
    async with lock:
        row = await run_in_threadpool(jobs.get_upload, svc.store, upload_id)
        if row["submission_id"] is not None:
            raise HTTPException(409, "this upload is already complete")
        offset = row["received_bytes"]
        if upload_offset != offset:
            raise HTTPException(409, f"Upload-Offset {upload_offset} does not match the stored offset {offset}; "
                                "HEAD the upload and resume from there", headers=_headers(row))
        part = svc.settings.uploads_dir / f"{upload_id}.part"
        _check_part(part, row)
        # Bytes past the committed offset (a crash mid-PATCH) are not trusted: cut them.
        with open(part, "ab") as f:
            f.truncate(offset)
        limit = await run_in_threadpool(svc.upload_limit, key)
        limit = min(limit, svc.settings.max_upload_bytes) - offset
        if row["declared_length"] is not None:
            limit = min(limit, row["declared_length"] - offset)
        try:
            written, _ = await stream_body_to(request, part, max(0, limit), mode="ab")
        except BodyTooLarge:
            with open(part, "ab") as f:
                f.truncate(offset)
            raise HTTPException(413, f"this chunk would take the upload past its limit ({offset + max(0, limit)} "
                                "bytes: declared Upload-Length, the server's WOSAC_MAX_UPLOAD_BYTES or the key's "
                                "daily quota)", headers=_headers(row))
        await run_in_threadpool(jobs.set_upload_offset, svc.store, upload_id, offset + written)
    svc.upload_locks.pop(upload_id, None)
    return Response(status_code=204, headers={"Upload-Offset": str(offset + written)})


@router.post("/{upload_id}/complete", status_code=202, response_model=SubmissionStatus,
             operation_id="completeUpload",
             responses={202: SUBMISSION_LINKS, 409: {"description": "Upload incomplete"}})
async def complete_upload(svc: ServiceDep, key: Key, upload_id: UploadId):
    """Turn the uploaded bytes into a queued submission (idempotent)."""
    row = await run_in_threadpool(svc.own_upload, key, upload_id)
    lock = svc.upload_locks.setdefault(upload_id, asyncio.Lock())
    async with lock:
        row = await run_in_threadpool(jobs.get_upload, svc.store, upload_id)
        if row["submission_id"] is not None:
            return svc.accepted(await run_in_threadpool(jobs.get_submission, svc.store, row["submission_id"]))
        if row["declared_length"] is not None and row["received_bytes"] != row["declared_length"]:
            raise HTTPException(409, f"received {row['received_bytes']} of the {row['declared_length']} declared "
                                "bytes; PATCH the rest first", headers=_headers(row))
        part = svc.settings.uploads_dir / f"{upload_id}.part"
        _check_part(part, row)
        with open(part, "ab") as f:
            f.truncate(row["received_bytes"])  # only the committed bytes count
        try:
            sub = await run_in_threadpool(
                svc.accept, key, part, row["received_bytes"], method=row["method"], challenge=row["challenge"],
                config=row["config"], allow_partial=bool(row["allow_partial"]), publish=bool(row["published"]),
                upload_id=upload_id)
        except HTTPException as exc:
            if exc.status_code != 429:  # a quota may free up: keep the bytes; the rest is final
                part.unlink(missing_ok=True)
                await run_in_threadpool(svc.store.execute, "DELETE FROM uploads WHERE id = ?", (upload_id,))
            raise
    svc.upload_locks.pop(upload_id, None)
    return svc.accepted(sub)


@router.delete("/{upload_id}", status_code=204, operation_id="deleteUpload")
def delete_upload(svc: ServiceDep, key: Key, upload_id: UploadId):
    """Abandon an unfinished upload and free its disk space."""
    row = svc.own_upload(key, upload_id)
    if row["submission_id"] is not None:
        raise HTTPException(409, "this upload was completed; it is a submission now")
    (svc.settings.uploads_dir / f"{upload_id}.part").unlink(missing_ok=True)
    svc.store.execute("DELETE FROM uploads WHERE id = ?", (upload_id,))
    return Response(status_code=204)
