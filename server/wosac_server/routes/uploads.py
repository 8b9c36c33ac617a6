"""`/v1/uploads`: resumable uploads, tus 1.0.0 (core, creation, termination, expiration, checksum).

`OPTIONS` tells the protocol; `POST` creates an upload (`Upload-Length`, the submission's parameters in
`Upload-Metadata`); `PATCH` appends at `Upload-Offset`; `HEAD` gives the offset after a dropped
connection; `DELETE` abandons it. An upload created through tus becomes a queued submission when its
last byte arrives: its id is in the `Submission-Id` header of that `PATCH`, of `HEAD`, and in `GET`'s
answer. The earlier form of this resource (no `Tus-Resumable`, parameters in the query, `POST
.../complete`) is still served. HTTP only here: the rules are `resumable.Resumable`'s.
"""

from __future__ import annotations

import email.utils
from typing import Annotated

from fastapi import APIRouter, Depends, Header, Request, Response
from fastapi.responses import JSONResponse

from ..errors import BadRequest, NotASubmission
from ..models import SubmissionStatus, UploadStatus
from ..resumable import Chunk, UploadsDep
from ..service import Key, ServiceDep
from . import tus
from .answers import TUS_VERSION, upload_headers
from .params import MAX_HEADER_INT, OCTET_BODY, SUBMISSION_LINKS, UPLOAD_LINKS, ClientBody, Params, UploadId
from .submissions import accepted

router = APIRouter(prefix="/v1/uploads", tags=["uploads"])
DISK_FULL = {"description": "The server's disk is full or past its floor; retry after Retry-After seconds"}
Tus = Annotated[bool, Depends(tus.speaks_tus)]
HeaderInt = Annotated[int | None, Header(ge=0, le=MAX_HEADER_INT)]
CHUNK_TYPE = "application/offset+octet-stream"


def _headers(row: dict, expires_at: float) -> dict[str, str]:
    """An upload's headers: its position, when it expires (unfinished), its metadata, its submission."""
    extra = {}
    if row["submission_id"] is not None:
        extra["Submission-Id"] = row["submission_id"]
    else:
        extra["Upload-Expires"] = email.utils.formatdate(expires_at, usegmt=True)
    if row.get("metadata"):
        extra["Upload-Metadata"] = row["metadata"]
    return upload_headers(row["received_bytes"], row["declared_length"], **extra)


def _status(row: dict) -> dict:
    return UploadStatus(
        upload_id=row["id"],
        offset=row["received_bytes"],
        length=row["declared_length"],
        submission_id=row["submission_id"],
    ).model_dump()


@router.options("", status_code=204, operation_id="uploadOptions")
@router.options("/{upload_id}", status_code=204, include_in_schema=False)
def upload_options(svc: ServiceDep):
    """tus discovery: the version, extensions, largest upload and checksum algorithms served (no key)."""
    return Response(status_code=204, headers=tus.discovery_headers(svc.settings.max_upload_bytes))


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
    uploads: UploadsDep,
    key: Key,
    speaks_tus: Tus,
    query: Params,
    upload_length: Annotated[int | None, Header(ge=1, le=MAX_HEADER_INT)] = None,
    upload_metadata: Annotated[str | None, Header()] = None,
):
    """Start a resumable upload of `Upload-Length` bytes, the submission's parameters in `Upload-Metadata`
    (tus) or the query; send the bytes with PATCH."""
    if speaks_tus and upload_length is None:
        raise BadRequest("Upload-Length is required (this server does not defer the length)")
    metadata = tus.parse_metadata(upload_metadata or "")
    params = tus.submission_params(metadata, query)
    # A tus upload keeps its metadata as sent ("" when none): it becomes a submission on its last byte.
    kept = (upload_metadata or "").strip() if speaks_tus or upload_metadata is not None else None
    row = uploads.create(key, params, upload_length, kept)
    headers = {**_headers(row, uploads.expires_at(row)), "Location": f"/v1/uploads/{row['id']}"}
    return JSONResponse(_status(row), status_code=201, headers=headers)


@router.head("/{upload_id}", operation_id="headUpload")
async def head_upload(uploads: UploadsDep, key: Key, upload_id: UploadId, speaks_tus: Tus):
    """The current offset (`Upload-Offset`); a tus upload whose bytes are all in is made a submission if it
    is not yet one (its id in `Submission-Id`)."""
    row = await uploads.view(key, upload_id)
    return Response(status_code=200, headers=_headers(row, uploads.expires_at(row)))


@router.get("/{upload_id}", response_model=UploadStatus, operation_id="getUpload")
async def get_upload(uploads: UploadsDep, key: Key, upload_id: UploadId):
    """The upload's offset, length and, once it is a submission, `submission_id` (as `HEAD`)."""
    row = await uploads.view(key, upload_id)
    return JSONResponse(_status(row), headers=_headers(row, uploads.expires_at(row)))


@router.patch(
    "/{upload_id}",
    status_code=204,
    openapi_extra=OCTET_BODY,
    operation_id="patchUpload",
    responses={
        409: {"description": "Upload-Offset does not match, or another request is at work"},
        413: {"description": "Chunk would exceed the size limit"},
        460: {"description": "The chunk's Upload-Checksum does not match its bytes (they are dropped)"},
        507: DISK_FULL,
    },
)
async def patch_upload(
    request: Request,
    uploads: UploadsDep,
    key: Key,
    upload_id: UploadId,
    speaks_tus: Tus,
    upload_offset: Annotated[int, Header(ge=0, le=MAX_HEADER_INT)],
    content_length: HeaderInt = None,
    upload_checksum: Annotated[str | None, Header()] = None,
):
    """Append the body at `Upload-Offset`; answers the new offset in `Upload-Offset` (and `Submission-Id`
    when this chunk completed a tus upload)."""
    if speaks_tus and request.headers.get("content-type", "").split(";")[0].strip().lower() != CHUNK_TYPE:
        raise NotASubmission(f"a tus PATCH carries Content-Type: {CHUNK_TYPE}")
    checksum = tus.parse_checksum(upload_checksum) if upload_checksum is not None else None
    chunk = Chunk(offset=upload_offset, length=content_length, checksum=checksum)
    row = await uploads.write(key, upload_id, chunk, ClientBody(request))
    return Response(status_code=204, headers=_headers(row, uploads.expires_at(row)))


@router.post(
    "/{upload_id}/complete",
    status_code=202,
    response_model=SubmissionStatus,
    operation_id="completeUpload",
    responses={202: SUBMISSION_LINKS, 409: {"description": "Upload incomplete, or another request at work"}},
)
async def complete_upload(uploads: UploadsDep, key: Key, upload_id: UploadId):
    """Turn the uploaded bytes into a queued submission (idempotent; the earlier form's last step, which a
    tus upload takes by itself on its last byte)."""
    return accepted(await uploads.complete(key, upload_id))


@router.delete("/{upload_id}", status_code=204, operation_id="deleteUpload")
def delete_upload(uploads: UploadsDep, key: Key, upload_id: UploadId):
    """Abandon an unfinished upload and free its disk space (tus termination)."""
    uploads.delete(key, upload_id)
    return Response(status_code=204, headers={"Tus-Resumable": TUS_VERSION})
