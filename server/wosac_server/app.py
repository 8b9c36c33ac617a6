"""The HTTP API (FastAPI): uploads, submission status, results, leaderboards, web page.

Uploads are streamed to a server-named file inside the data dir in chunks
(never read whole into memory), fsynced, renamed, and only then is the job row
committed and `202` answered: an accepted submission survives any crash after
the answer. Large uploads can be resumed (tus 1.0.0, `routes.uploads`).
Scoring itself happens in worker processes (`worker.py`); this process only
reads and writes the job store.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import sys
from contextlib import asynccontextmanager

import anyio
from fastapi import FastAPI, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.middleware.cors import CORSMiddleware

from . import disk
from .guard import CloseUnreadBodies
from .reading import Reading
from .resumable import Resumable
from .routes import answers, public, submissions, uploads
from .routes.answers import TUS_ANSWER_HEADERS, TUS_REQUEST_HEADERS
from .service import Service
from .settings import Settings, load_settings
from .web import install_pages, install_scene_pages

log = logging.getLogger("wosac_server.app")
MAINTENANCE_S = 5.0  # how often upload states a full disk left unrecorded are retried, the reserve remade


async def _maintain(svc: Service) -> None:
    while True:
        await asyncio.sleep(MAINTENANCE_S)
        try:
            await run_in_threadpool(svc.maintain)
        except Exception as exc:  # noqa: BLE001 - the database or disk may be unwell; the next round retries
            log.warning("maintenance round failed: %s", exc)


async def _disk_full_answer(request: Request, exc: Exception):
    """Any request that needed space and found none (ENOSPC, EDQUOT, SQLITE_FULL): 507, not 500."""
    if not disk.is_disk_full(exc):
        raise exc
    log.warning("%s %s: the data dir's disk is full (%s)", request.method, request.url.path, exc)
    return await answers.refusal(request, disk.full_answer())


def _allow_origins(app: FastAPI, origins: list[str]) -> None:
    """CORS for the origins configured (WOSAC_CORS_ORIGINS; none by default): a page of another origin may
    upload through tus and read the answers' tus headers. Never with credentials: the API's key travels
    in `Authorization`, which the page sets itself, so no cookie or ambient credential is ever allowed,
    and `*` stays a plain wildcard."""
    if not origins:
        return
    app.add_middleware(
        CORSMiddleware,
        allow_origins=origins,
        allow_credentials=False,
        allow_methods=["GET", "HEAD", "POST", "PATCH", "DELETE", "OPTIONS"],
        allow_headers=["Authorization", "Content-Type", *TUS_REQUEST_HEADERS],
        expose_headers=["Location", "Retry-After", "Submission-Id", *TUS_ANSWER_HEADERS],
        max_age=600,
    )


def create_app(settings: Settings | None = None) -> FastAPI:
    svc = Service(settings or load_settings())

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        # A few threads for the blocking work of requests (database, files, upload checks): with dozens
        # runnable, the event loop waits its turn for the GIL behind all of them and /healthz stalls.
        anyio.to_thread.current_default_thread_limiter().total_tokens = svc.settings.api_threads
        sys.setswitchinterval(0.001)  # and it waits at most ~1 ms per thread that holds the GIL
        maintenance = asyncio.create_task(_maintain(svc))
        yield
        maintenance.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await maintenance
        svc.store.close()

    app = FastAPI(
        title="wosac-eval scoring service",
        version="2",
        description="Upload a WOSAC submission (sim agents or scenario generation), follow its scoring, "
        "fetch exact results.",
        lifespan=lifespan,
        # The interactive docs pages load their scripts from a CDN; the schema alone is served.
        docs_url=None,
        redoc_url=None,
    )
    app.state.service = svc
    app.state.settings = svc.settings  # kept for the worker pool and tests
    app.state.store = svc.store
    app.state.reading = Reading(svc)
    app.state.uploads = Resumable(svc)
    for module in (public, submissions, uploads):
        app.include_router(module.router)
    answers.install(app)
    install_pages(app, svc)
    install_scene_pages(app, svc)
    for error_type in disk.full_error_types(svc.store.dialect):
        app.add_exception_handler(error_type, _disk_full_answer)
    app.add_middleware(CloseUnreadBodies)  # an early answer closes its connection: no unread body is waited for
    _allow_origins(app, svc.settings.cors_origin_list)
    return app
