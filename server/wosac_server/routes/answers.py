"""The one translation of the service's refusals (`errors`) into HTTP: a status code, headers, and
`{"detail": ...}`; and the headers every answer about a resumable upload carries (tus 1.0.0).

To add a refusal: a kind in `errors.py`, its status here. Nothing else maps errors to statuses.
"""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from .. import errors

TUS_VERSION = "1.0.0"
TUS_REQUEST_HEADERS = ["Tus-Resumable", "Upload-Length", "Upload-Offset", "Upload-Metadata", "Upload-Checksum"]
TUS_ANSWER_HEADERS = [
    "Tus-Resumable",
    "Tus-Version",
    "Tus-Extension",
    "Tus-Max-Size",
    "Tus-Checksum-Algorithm",
    "Upload-Offset",
    "Upload-Length",
    "Upload-Expires",
    "Upload-Metadata",
]
# tus's own code for a chunk whose checksum does not match (the protocol's checksum extension).
CHECKSUM_MISMATCH = 460

STATUS: dict[type[errors.ServiceError], int] = {
    errors.BadRequest: 400,
    errors.Unauthenticated: 401,
    errors.NotOwner: 403,
    errors.NotFound: 404,
    errors.Conflict: 409,
    errors.Gone: 410,
    errors.VersionUnsupported: 412,
    errors.TooLarge: 413,
    errors.NotASubmission: 415,
    errors.Invalid: 422,
    errors.TooMany: 429,
    errors.ChecksumMismatch: CHECKSUM_MISMATCH,
    errors.NoSpace: 507,
}


def status_of(exc: errors.ServiceError) -> int:
    return STATUS[type(exc)]


def upload_headers(offset: int, length: int | None, **extra: str) -> dict[str, str]:
    """The headers of an answer about a resumable upload: its position, never cached, tus's version."""
    headers = {"Tus-Resumable": TUS_VERSION, "Upload-Offset": str(offset), "Cache-Control": "no-store"}
    if length is not None:
        headers["Upload-Length"] = str(length)
    return {**headers, **extra}


def headers_of(exc: errors.ServiceError, path: str) -> dict[str, str]:
    headers: dict[str, str] = {}
    if exc.upload is not None:
        headers.update(upload_headers(exc.upload.offset, exc.upload.length))
    elif path.startswith("/v1/uploads"):
        headers["Tus-Resumable"] = TUS_VERSION
    if isinstance(exc, errors.VersionUnsupported):
        headers["Tus-Version"] = TUS_VERSION
    if exc.retry_after_s is not None:
        headers["Retry-After"] = str(exc.retry_after_s)
    if isinstance(exc, errors.Unauthenticated):
        headers["WWW-Authenticate"] = 'Bearer error="invalid_token"' if exc.sent_a_key else "Bearer"
    return headers


async def refusal(request: Request, exc: Exception) -> JSONResponse:
    """The answer to a `ServiceError` raised anywhere under a route."""
    assert isinstance(exc, errors.ServiceError)  # registered for that class alone
    return JSONResponse({"detail": exc.detail}, status_code=status_of(exc), headers=headers_of(exc, request.url.path))


def install(app: FastAPI) -> None:
    app.add_exception_handler(errors.ServiceError, refusal)
