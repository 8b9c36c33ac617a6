"""The service layer's resumable uploads (tus 1.0.0, and the earlier form of the same resource).

An upload is created with its length and the submission's parameters, receives chunks at the offset
the server holds (each fsynced before its offset is committed), and becomes a queued submission:
at once when its last byte arrives through tus (a request carrying `Tus-Resumable`), or on `complete`
in the earlier form. Its state lives in the database (open, writing, completing, deleting): every
chunk, completion and deletion first moves it out of `open` with a compare-and-set, so at most one
works on an upload at a time (the others get `Conflict`), and moves it on when it ends, even on a
full disk (`Service.settle_upload`).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from fastapi import Depends, Request
from fastapi.concurrency import run_in_threadpool

from . import auth, disk, jobs
from .errors import (
    ChecksumMismatch,
    Conflict,
    Gone,
    NotFound,
    NotOwner,
    ServiceError,
    TooLarge,
    TooMany,
    UploadPosition,
)
from .service import Service, SubmissionParams
from .uploads import Body, BodyTooLarge, Digest, stream_body_to

# Refusals at completion that may pass (a job slot frees up, the day rolls on; a taken name is released by
# an operator): the uploaded bytes are kept for another try. Any other refusal drops them with the upload.
KEEPS_BYTES = (TooMany, NotOwner)
MAX_METADATA_CHARS = 4096


@dataclass(frozen=True)
class Chunk:
    """A PATCH as the service sees it: where it claims to start, and its checksum when one was sent."""

    offset: int
    length: int | None  # Content-Length, when sent
    checksum: tuple[str, bytes] | None = None  # (algorithm of uploads.CHECKSUMS, digest)


def through_tus(row: dict) -> bool:
    """Whether the upload was created through tus (its metadata kept, "" when none): it becomes a
    submission on its last byte. The earlier form's uploads wait for `complete`."""
    return row.get("metadata") is not None


def position(row: dict) -> UploadPosition:
    return UploadPosition(row["received_bytes"], row["declared_length"])


def busy(row: dict | None) -> ServiceError:
    """Why an upload cannot take this request now (its state is not `open`)."""
    if row is None or row["state"] == "deleting":
        return NotFound("this upload is gone (deleted, expired, or refused when completed)")
    if row["submission_id"] is not None:
        return Conflict("this upload is already complete", upload=position(row))
    doing = {"writing": "a PATCH", "completing": "a complete"}.get(row["state"], row["state"])
    return Conflict(f"{doing} of this upload is in progress; retry when it is done", upload=position(row))


class Resumable:
    """The rules of resumable uploads, over one `Service`."""

    def __init__(self, svc: Service):
        self.svc = svc

    def part(self, upload_id: str) -> Path:
        return self.svc.settings.uploads_dir / f"{upload_id}.part"

    def expires_at(self, row: dict) -> float:
        """When an unfinished upload left alone since its last request expires (WOSAC_UPLOAD_TTL_S)."""
        return row["updated_at"] + self.svc.settings.upload_ttl_s

    def own(self, key: auth.ApiKey, upload_id: str) -> dict:
        """The key's upload (`NotFound` for another key's, a deleted or an expired one)."""
        row = self.svc.own_upload(key, upload_id)
        if row["submission_id"] is None and self.expires_at(row) < time.time():
            raise NotFound(f"upload {upload_id} expired (unfinished for WOSAC_UPLOAD_TTL_S); start a new upload")
        return row

    # -- creation ----------------------------------------------------------------------------------
    def create(self, key: auth.ApiKey, asked: SubmissionParams, length: int | None, metadata: str | None) -> dict:
        """A new upload of `length` bytes (None: told at `complete`), its parameters checked now (runs in a
        thread); its row."""
        params = self.svc.resolve(key, asked)
        self.svc.refuse_early(key, length)
        upload_id = jobs.new_id()
        part = self.part(upload_id)
        declared = length or 0
        # The space check and the promise (the row, whose declared bytes count as reserved) as one step.
        with self.svc.space_gate:
            self.svc.need_space(declared + disk.job_need_bytes(declared))
            part.touch()
            try:
                with self.svc.store.transaction():  # the count and the insert under one write lock
                    held = jobs.open_uploads(self.svc.store, key.id)
                    if held >= self.svc.settings.max_open_uploads:
                        raise TooMany(
                            f"key {key.name!r} has {held} unfinished uploads, its limit "
                            f"(WOSAC_MAX_OPEN_UPLOADS); complete or DELETE one first"
                        )
                    jobs.insert_upload(
                        self.svc.store, upload_id, key.id, params, declared_length=length, metadata=metadata
                    )
            except BaseException:
                part.unlink(missing_ok=True)
                raise
        return jobs.held_upload(self.svc.store, upload_id)

    # -- chunks ------------------------------------------------------------------------------------
    async def write(self, key: auth.ApiKey, upload_id: str, chunk: Chunk, body: Body) -> dict:
        """Append `body` at `chunk.offset`; the upload's row after it (after its completion when it was
        created through tus and its last byte is in: `submission_id` set)."""
        known = await run_in_threadpool(self.own, key, upload_id)
        # A declared upload's bytes are promised (reserved) already; an undeclared one's chunk is promised here.
        await run_in_threadpool(self.svc.need_space, 0 if known["declared_length"] is not None else chunk.length or 0)
        # open -> writing, atomically: a PATCH never overlaps another PATCH, a complete or a DELETE.
        if not await run_in_threadpool(jobs.move_upload, self.svc.store, upload_id, "open", "writing"):
            raise busy(await run_in_threadpool(jobs.get_upload, self.svc.store, upload_id))
        try:
            row = await run_in_threadpool(jobs.held_upload, self.svc.store, upload_id)
            await self._append(key, row, chunk, body)
        finally:
            # Never left `writing`: settle_upload frees the disk reserve, or retries later, when it cannot write.
            await run_in_threadpool(self.svc.settle_upload, upload_id, "writing", "open")
        row = await run_in_threadpool(jobs.held_upload, self.svc.store, upload_id)
        return await self.finish(key, row)

    async def _append(self, key: auth.ApiKey, row: dict, chunk: Chunk, body: Body) -> None:
        upload_id, offset = row["id"], row["received_bytes"]
        if chunk.offset != offset:
            raise Conflict(
                f"Upload-Offset {chunk.offset} does not match the stored offset {offset}; "
                "HEAD the upload and resume from there",
                upload=position(row),
            )
        part = self._checked_part(row)
        cut(part, offset)  # bytes past the committed offset (a crash mid-PATCH) are not trusted
        limit = await run_in_threadpool(self.svc.upload_limit, key, upload_id) - offset
        if row["declared_length"] is not None:
            limit = min(limit, row["declared_length"] - offset)
        digest = Digest(chunk.checksum[0]) if chunk.checksum else None
        try:
            written = await stream_body_to(body, part, max(0, limit), mode="ab", digest=digest)
            if digest is not None and chunk.checksum and digest.digest() != chunk.checksum[1]:
                raise ChecksumMismatch(
                    f"the chunk's {chunk.checksum[0]} checksum does not match its {written} bytes; they were "
                    f"dropped (the upload keeps its {offset} bytes before them): send the chunk again",
                    upload=position(row),
                )
            await run_in_threadpool(jobs.set_upload_offset, self.svc.store, upload_id, offset + written)
        except BodyTooLarge:
            cut(part, offset)
            raise TooLarge(
                f"this chunk would take the upload past its limit ({offset + max(0, limit)} "
                "bytes: declared Upload-Length, the server's WOSAC_MAX_UPLOAD_BYTES or the key's "
                "daily quota)",
                upload=position(row),
            ) from None
        except BaseException:
            # Bytes past the committed offset are cut at once: on a full disk their space lets the state be
            # recorded.
            cut(part, offset)
            raise

    def _checked_part(self, row: dict) -> Path:
        part = self.part(row["id"])
        # Never let truncate() pad a lost file with zeros: refuse instead.
        if not part.exists() or part.stat().st_size < row["received_bytes"]:
            raise Gone("the stored bytes of this upload are gone; start a new upload")
        return part

    # -- completion --------------------------------------------------------------------------------
    async def view(self, key: auth.ApiKey, upload_id: str) -> dict:
        """The key's upload as `HEAD` and `GET` show it: a tus upload whose bytes are all in (its completion
        refused for a while, or cut off) is made a submission first."""
        return await self.finish(key, await run_in_threadpool(self.own, key, upload_id))

    async def finish(self, key: auth.ApiKey, row: dict) -> dict:
        """The row of a full tus upload once it is a submission; as it is when another request is at its
        completion now (the client asks again), or when it is not a full tus upload. A refusal is raised as
        `complete` raises it."""
        full = row["declared_length"] is not None and row["received_bytes"] == row["declared_length"]
        if not through_tus(row) or row["submission_id"] is not None or not full or row["state"] != "open":
            return row
        with contextlib.suppress(Conflict):  # another request completes it: its answer, or a later HEAD, says
            await self.complete(key, row["id"])
        return await run_in_threadpool(jobs.held_upload, self.svc.store, row["id"])

    async def complete(self, key: auth.ApiKey, upload_id: str) -> dict:
        """Turn the uploaded bytes into a queued submission (idempotent); its job row."""
        await run_in_threadpool(self.own, key, upload_id)
        store = self.svc.store
        if not await run_in_threadpool(jobs.move_upload, store, upload_id, "open", "completing"):
            row = await run_in_threadpool(jobs.get_upload, store, upload_id)
            if row is not None and row["submission_id"] is not None:  # completed before: the same answer again
                done = await run_in_threadpool(jobs.get_submission, store, row["submission_id"])
                if done is None:
                    raise NotFound("this upload was completed; its submission was deleted since")
                return done
            raise busy(row)
        outcome = "open"  # what the upload becomes when this request ends
        try:
            row = await run_in_threadpool(jobs.held_upload, store, upload_id)
            if row["declared_length"] is not None and row["received_bytes"] != row["declared_length"]:
                raise Conflict(
                    f"received {row['received_bytes']} of the {row['declared_length']} declared "
                    "bytes; PATCH the rest first",
                    upload=position(row),
                )
            part = self._checked_part(row)
            cut(part, row["received_bytes"])  # only the committed bytes count
            try:
                submission = await self._accept(key, row, part)
            except KEEPS_BYTES:
                raise
            except ServiceError:
                outcome = "refused"
                part.unlink(missing_ok=True)
                raise
            outcome = "complete"
        finally:
            # "refused": the row goes too. Never left `completing` (see write).
            await run_in_threadpool(
                self.svc.settle_upload, upload_id, "completing", None if outcome == "refused" else outcome
            )
        return submission

    async def _accept(self, key: auth.ApiKey, row: dict, part: Path) -> dict:
        params = SubmissionParams(
            challenge=row["challenge"],
            config=row["config"],
            method=row["method"],
            publish=bool(row["published"]),
            allow_partial=bool(row["allow_partial"]),
        )
        async with self.svc.upload_slot(key) as hold, self.svc.check_slots:
            return await run_in_threadpool(
                self.svc.accept, key, part, row["received_bytes"], hold=hold, params=params, upload_id=row["id"]
            )

    # -- termination -------------------------------------------------------------------------------
    def delete(self, key: auth.ApiKey, upload_id: str) -> None:
        """Abandon an unfinished upload and free its disk space (runs in a thread)."""
        row = self.own(key, upload_id)
        if row["submission_id"] is not None:
            raise Conflict("this upload was completed; it is a submission now")
        if not self.svc.write_state(jobs.move_upload, self.svc.store, upload_id, "open", "deleting"):
            raise busy(jobs.get_upload(self.svc.store, upload_id))
        # The file first: its space is free even when the database cannot drop the row yet (retried later; a
        # `deleting` upload is gone to every request meanwhile).
        self.part(upload_id).unlink(missing_ok=True)
        self.svc.settle_upload(upload_id, "deleting", None)


def cut(part: Path, offset: int) -> None:
    """Drop a part file's bytes past `offset` (the committed ones); shrinking needs no space."""
    try:
        with open(part, "ab") as f:
            f.truncate(offset)
    except FileNotFoundError:
        pass


def uploads_of(request: Request) -> Resumable:
    """The dependency of the upload routes."""
    return request.app.state.uploads


UploadsDep = Annotated[Resumable, Depends(uploads_of)]
