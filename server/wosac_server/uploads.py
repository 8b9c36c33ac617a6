"""Upload mechanics: bodies streamed to disk in chunks (fsynced), at most a given number of bytes.

Nothing here holds a body in memory. The check of what was received is the reader's own
(`wosac_eval.parse.archive.check_container`, called by `Service.accept`).
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

from fastapi import HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

from .disk import RETRY_AFTER_S


class BodyTooLarge(Exception):
    pass


def disk_full(exc: OSError) -> HTTPException:
    return HTTPException(
        507,
        f"the server's disk is full ({os.strerror(exc.errno or 0)}); retry later "
        "(resumable uploads keep what was stored)",
        headers={"Retry-After": str(RETRY_AFTER_S)},
    )


async def stream_body_to(request: Request, path: Path, limit: int, mode: str = "wb") -> tuple[int, bool]:
    """Append the request body to `path` chunk by chunk, at most `limit` bytes.

    Returns (bytes written, client disconnected). Raises BodyTooLarge past the
    limit, without reading the rest of the body. The file
    is fsynced before returning, so the bytes counted are on disk.
    """
    written, disconnected = 0, False
    with open(path, mode) as f:
        try:
            stream = request.stream()
            async for chunk in stream:
                if written + len(chunk) > limit:
                    # The rest is not read: the answer carries `Connection: close` (guard.CloseUnreadBodies).
                    raise BodyTooLarge()
                f.write(chunk)
                written += len(chunk)
        except ClientDisconnect:
            disconnected = True
        except OSError as exc:
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                raise disk_full(exc) from exc
            raise
        f.flush()
        await run_in_threadpool(os.fsync, f.fileno())
    return written, disconnected
