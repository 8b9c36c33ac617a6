"""Upload mechanics: bodies streamed to disk in chunks (fsynced), archives checked before acceptance.

Nothing here holds a body in memory or extracts an archive to disk.
"""
from __future__ import annotations

import errno
import os
import tarfile
import zlib
from pathlib import Path, PurePosixPath

from fastapi import HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

# After refusing an oversized body, read (and drop) this much more so the client,
# still sending, gets to read our 413 instead of a reset connection.
DRAIN_AFTER_REFUSAL = 8 * 1024 * 1024


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


