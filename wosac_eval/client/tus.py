"""The tus 1.0.0 side of `submit`: create an upload, send the file's chunks at the server's offset, learn
the submission the upload became.

Creation sends `Upload-Length` and the submission's parameters in `Upload-Metadata`; each `PATCH` carries
its CRC32C (`Upload-Checksum`: a chunk damaged on the way is refused with 460 and sent again); the last
one's answer names the submission (`Submission-Id`), as does `HEAD` later. A dropped connection, a 5xx,
a full disk (`507`) or a rate limit (`429`) is retried from the offset the server reports.
"""

from __future__ import annotations

import base64
import contextlib
import re
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import google_crc32c

from wosac_eval.client.transport import (
    NETWORK_ERRORS,
    RETRYABLE_STATUS,
    ProtocolError,
    Response,
    Retrier,
    RetryPolicy,
    Server,
    SubmitError,
    call,
    refused,
    status_reason,
)

TUS_VERSION = "1.0.0"
BLOCK_BYTES = 2**20  # what is read from the file, and sent, at a time
CHECKSUM_MISMATCH = 460
_ID = re.compile(r"^[0-9a-f]{32}$")


class FileChanged(SubmitError):
    """The file changed (size or modification time) while it was being uploaded; the upload was deleted."""


class UploadGone(Exception):
    """The server no longer has the upload (404/410): expired, deleted, refused, or its bytes lost."""


def encode_metadata(values: dict[str, str]) -> str:
    """tus's `Upload-Metadata`: `key base64(value)` pairs, comma-separated."""
    return ",".join(f"{k} {base64.b64encode(v.encode()).decode()}" for k, v in values.items())


@dataclass
class Sender:
    """The tus exchanges of one file's upload; `offset` is the server's, as last known."""

    server: Server
    file: Path
    size: int
    policy: RetryPolicy
    log: Callable[[str], None]
    progress: Callable[[str, int, int | None], None]
    chunk: int
    mtime_ns: int
    limit_rate: int | None = None
    offset: int = 0
    sent: int = 0  # bytes sent in this run (a chunk sent again counts again)
    patches: int = 0  # PATCH requests answered in this run

    def __post_init__(self) -> None:
        self.block = max(4096, min(BLOCK_BYTES, self.limit_rate // 20)) if self.limit_rate else BLOCK_BYTES
        self._rate_start: float | None = None
        self._rate_bytes = 0

    @property
    def completion_s(self) -> float:
        """How long the server may take to answer the last chunk: it checks the whole upload first."""
        return 600 + self.size / 2**24

    # -- creation and the server's offset --------------------------------------------------------------
    def create(self, metadata: dict[str, str]) -> str:
        headers = {
            "Tus-Resumable": TUS_VERSION,
            "Upload-Length": str(self.size),
            "Upload-Metadata": encode_metadata(metadata),
        }
        answer = call(self, "creating the upload", "POST", "uploads", headers=headers)
        if answer.status != 201:
            raise refused(answer)
        if answer.headers.get("tus-resumable") != TUS_VERSION:
            raise ProtocolError(
                f"the server at {self.server.url} does not speak tus {TUS_VERSION} (no Tus-Resumable in its "
                "answer): it is older than this client, or not a wosac-server"
            )
        upload_id = answer.headers.get("location", "").rstrip("/").rsplit("/", 1)[-1]
        if not _ID.match(upload_id):
            raise ProtocolError(f"the server's answer to creating an upload names no upload (Location {upload_id!r})")
        return upload_id

    def head(self, upload_id: str, retrier: Retrier | None = None) -> str | None:
        """Sets `offset` to the server's; the submission the upload became, if it is one."""
        answer = call(
            self,
            "asking the server for the upload's offset",
            "HEAD",
            f"uploads/{upload_id}",
            headers={"Tus-Resumable": TUS_VERSION},
            retrier=retrier,
            deadline=self.completion_s,  # a full upload's HEAD makes its submission: the whole check
        )
        if answer.status in (404, 410):
            raise UploadGone(
                f"the server no longer has upload {upload_id} ({answer.status}: expired, deleted, or its bytes lost)"
            )
        if answer.status != 200:
            raise refused(answer)
        declared = answer.headers.get("upload-length")
        if declared is not None and declared != str(self.size):
            raise UploadGone(f"upload {upload_id} on the server was declared {declared} bytes long, not {self.size}")
        self.offset = self._checked_offset(answer.offset(), "HEAD")
        self.progress("upload", self.offset, self.size)
        return answer.headers.get("submission-id")

    def _checked_offset(self, offset: int | None, what: str) -> int:
        if offset is None or not 0 <= offset <= self.size:
            raise ProtocolError(f"the server's {what} answer gives the offset {offset!r} for a {self.size}-byte upload")
        return offset

    # -- chunks --------------------------------------------------------------------------------------
    def send(self, upload_id: str) -> str:
        """PATCH chunks from `offset` to the end, resyncing to the server's offset after any failure; the id
        of the submission the upload became."""
        path = self.server.path(f"uploads/{upload_id}")
        retrier = Retrier(self.policy, self.log)
        with open(self.file, "rb") as f:
            while True:
                if self.offset == self.size:
                    return self._submission(upload_id, retrier)
                length = min(self.chunk, self.size - self.offset)
                headers = {
                    "Tus-Resumable": TUS_VERSION,
                    "Upload-Offset": str(self.offset),
                    "Content-Type": "application/offset+octet-stream",
                    "Upload-Checksum": f"crc32c {self._crc32c(f, self.offset, length)}",
                }
                last = self.offset + length == self.size
                if last:  # the last chunk makes the submission: of the file as it was when the upload began
                    self._check_unchanged(upload_id)
                try:
                    answer = self.server.request(
                        "PATCH",
                        path,
                        headers,
                        self._pieces(f, self.offset, length),
                        length,
                        timeout=self.completion_s if last else None,
                    )
                except NETWORK_ERRORS as error:
                    retrier.network_failure(self.server, "uploading", error)
                    if submission := self.head(upload_id, retrier):  # a dropped PATCH's bytes that arrived are kept
                        return submission
                    continue
                self.patches += 1
                if submission := self._after(upload_id, answer, retrier):
                    return submission

    def _after(self, upload_id: str, answer: Response, retrier: Retrier) -> str | None:
        """Reads a PATCH's answer: the submission when the upload became one; else `offset` set for the next."""
        held = answer.offset()
        if answer.status == 204:
            self.offset = self._checked_offset(held, "PATCH")
            retrier.reset()  # progress: the tries start again
            return answer.headers.get("submission-id")
        if answer.status in (404, 410):
            raise UploadGone(f"the server no longer has upload {upload_id} ({answer.status}: {answer.detail()})")
        if answer.status == 409 and held is not None and held != self.offset:
            self.log(f"the server holds {held:,} bytes of upload {upload_id}, not {self.offset:,}: going on from there")
            self.offset = self._checked_offset(held, "PATCH")
            self.progress("upload", self.offset, self.size)
            return None
        if answer.status == 409:  # another request at work on it: an interrupted one, still being read
            reason, retry_after, refusal = f"409 {answer.detail()}", answer.retry_after(), None
        elif answer.status == CHECKSUM_MISMATCH:  # damaged on the way: sent again
            reason, retry_after, refusal = f"460 {answer.detail()}", None, None
        elif answer.status in RETRYABLE_STATUS:
            reason, retry_after, refusal = status_reason(answer)
        else:
            raise refused(answer)
        self.progress("upload", self.offset, self.size)
        retrier.wait("uploading", reason, retry_after, refusal)
        return self.head(upload_id, retrier)

    def _submission(self, upload_id: str, retrier: Retrier) -> str:
        """All bytes are in, but no answer named the submission (its completion cut off, or at work in
        another request): ask until the server says, for as long as a completion may take."""
        deadline = time.monotonic() + self.completion_s
        wait = 0.5
        while time.monotonic() < deadline:
            submission = self.head(upload_id, retrier)
            if submission:
                return submission
            time.sleep(wait)
            wait = min(wait * 1.5, 10.0)
        raise SubmitError(
            f"upload {upload_id} holds the whole file, but the server named no submission within "
            f"{self.completion_s:.0f} s; run the same command again later to ask again"
        )

    def _check_unchanged(self, upload_id: str) -> None:
        stat = self.file.stat()
        if (stat.st_size, stat.st_mtime_ns) != (self.size, self.mtime_ns):
            with contextlib.suppress(*NETWORK_ERRORS):
                self.server.request("DELETE", self.server.path(f"uploads/{upload_id}"), {"Tus-Resumable": TUS_VERSION})
            raise FileChanged(
                f"{self.file} changed while it was being uploaded (its size or modification time); "
                f"upload {upload_id} was deleted: run the command again to send the file as it is now"
            )

    def _crc32c(self, f: Any, offset: int, length: int) -> str:
        """The chunk's CRC32C (read once before it is sent: the header goes first), base64."""
        checksum = google_crc32c.Checksum()
        f.seek(offset)
        done = 0
        while done < length:
            data = f.read(min(BLOCK_BYTES, length - done))
            if not data:
                raise SubmitError(f"{self.file} got shorter while it was being uploaded")
            checksum.update(data)
            done += len(data)
        return base64.b64encode(checksum.digest()).decode()

    def _pieces(self, f: Any, offset: int, length: int) -> Iterator[bytes]:
        """The chunk's bytes, a block at a time, paced to limit_rate; progress as they go."""
        f.seek(offset)
        done = 0
        while done < length:
            data = f.read(min(self.block, length - done))
            if not data:
                raise SubmitError(f"{self.file} got shorter while it was being uploaded")
            yield data
            done += len(data)
            self.sent += len(data)
            self.progress("upload", offset + done, self.size)
            if self.limit_rate:
                self._pace(len(data), self.limit_rate)

    def _pace(self, n: int, limit_rate: int) -> None:
        now = time.monotonic()
        if self._rate_start is None or now - self._rate_start > 10 + self._rate_bytes / limit_rate:
            self._rate_start, self._rate_bytes = now, 0  # (re)start after a long pause: no burst to catch up
        self._rate_bytes += n
        ahead = self._rate_bytes / limit_rate - (time.monotonic() - self._rate_start)
        if ahead > 0:
            time.sleep(ahead)
