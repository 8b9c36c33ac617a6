"""The service layer's single-request upload: a whole submission as one body, held, streamed to disk,
checked and queued (`POST /v1/submissions`).

The key's job slot (and the body's declared bytes of its day) is held before a byte is read, the
disk's room for the body counted while it comes, and the job row committed only once the file is
fsynced and renamed (`Service.accept`).
"""

from __future__ import annotations

from fastapi.concurrency import run_in_threadpool

from . import auth, jobs
from .errors import BadRequest
from .service import Service, SubmissionParams
from .uploads import Body, BodyTooLarge, stream_body_to


async def receive_submission(
    svc: Service, key: auth.ApiKey, body: Body, declared: int | None, asked: SubmissionParams
) -> dict:
    """The job row of a submission sent whole as `body` (`declared`: its Content-Length, when sent)."""
    params = await run_in_threadpool(svc.resolve, key, asked)
    async with svc.upload_slot(key, declared) as hold:  # 429/413 here, before a byte is read
        limit = await run_in_threadpool(svc.upload_limit, key, None, hold, True)
        temp = svc.settings.uploads_dir / f"{jobs.new_id()}.body"
        await run_in_threadpool(svc.admit_body, temp, declared)  # 507 when the disk has no room for it
        try:
            try:
                size = await stream_body_to(body, temp, limit)
            except BodyTooLarge:
                raise svc.too_large(key) from None
            if body.cut or (declared is not None and size != declared):
                raise BadRequest(
                    f"the body ended after {size} bytes (client disconnected or sent "
                    "less than Content-Length); use /v1/uploads to resume large uploads"
                )
            async with svc.check_slots:
                return await run_in_threadpool(svc.accept, key, temp, size, hold=hold, params=params)
        finally:
            temp.unlink(missing_ok=True)  # gone already when accepted (renamed)
            svc.forget_body(temp)  # the job row counts its files from here on
