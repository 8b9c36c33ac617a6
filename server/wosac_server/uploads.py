"""Upload mechanics: bodies streamed to disk in chunks (fsynced), at most a given number of bytes,
optionally hashed on the way (tus's checksum extension).

Nothing here holds a body in memory. The check of what was received is the reader's own
(`wosac_eval.parse.archive.check_container`, called by `Service.accept`).
"""

from __future__ import annotations

import errno
import hashlib
import os
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Protocol

import google_crc32c
from fastapi.concurrency import run_in_threadpool

from .disk import RETRY_AFTER_S
from .errors import NoSpace

# Checksum algorithms of `Upload-Checksum` (tus's checksum extension), by their tus names. CRC32C is
# computed in C (google-crc32c, the library's dependency for TFRecord framing) at disk speed.
CHECKSUMS = ("sha1", "sha256", "md5", "crc32c")


class Body(Protocol):
    """A request's body as the service reads it: its chunks, and `cut` once the client went away before
    sending all of it (what arrived before is still there)."""

    cut: bool

    def __aiter__(self) -> AsyncIterator[bytes]: ...


class BodyTooLarge(Exception):
    pass


class Digest:
    """A running checksum of a chunk's bytes under one of `CHECKSUMS`."""

    def __init__(self, algorithm: str):
        self.algorithm = algorithm
        running = google_crc32c.Checksum() if algorithm == "crc32c" else hashlib.new(algorithm)
        self.update: Callable[[bytes], object] = running.update
        self.digest: Callable[[], bytes] = running.digest


def disk_full(exc: OSError) -> NoSpace:
    return NoSpace(
        f"the server's disk is full ({os.strerror(exc.errno or 0)}); retry later "
        "(resumable uploads keep what was stored)",
        retry_after_s=RETRY_AFTER_S,
    )


async def stream_body_to(body: Body, path: Path, limit: int, mode: str = "wb", digest: Digest | None = None) -> int:
    """Append `body` to `path` chunk by chunk, at most `limit` bytes; returns the bytes written.

    Raises BodyTooLarge past the limit, without reading the rest of the body. The file is fsynced
    before returning, so the bytes counted are on disk.
    """
    written = 0
    with open(path, mode) as f:
        try:
            async for chunk in body:
                if written + len(chunk) > limit:
                    # The rest is not read: the answer carries `Connection: close` (guard.CloseUnreadBodies).
                    raise BodyTooLarge()
                f.write(chunk)
                if digest is not None:
                    digest.update(chunk)
                written += len(chunk)
        except OSError as exc:
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                raise disk_full(exc) from exc
            raise
        f.flush()
        await run_in_threadpool(os.fsync, f.fileno())
    return written
