"""The HTTP API (FastAPI): uploads, submission status, results, leaderboards, web page.

Uploads are streamed to a server-named file inside the data dir in chunks
(never read whole into memory), fsynced, renamed, and only then is the job row
committed and `202` answered: an accepted submission survives any crash after
the answer. Large uploads can be resumed (tus-like, `routes.uploads`).
Scoring itself happens in worker processes (`worker.py`); this process only
reads and writes the job store.
"""
from __future__ import annotations

import sys
from contextlib import asynccontextmanager

import anyio

from fastapi import FastAPI

from .guard import CloseUnreadBodies
from .routes import public, submissions, uploads
from .service import Service
from .settings import Settings, load_settings
from .web import install_pages


def create_app(settings: Settings | None = None) -> FastAPI:
    svc = Service(settings or load_settings())

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        # A few threads for the blocking work of requests (database, files, upload checks): with dozens
        # runnable, the event loop waits its turn for the GIL behind all of them and /healthz stalls.
        anyio.to_thread.current_default_thread_limiter().total_tokens = svc.settings.api_threads
        sys.setswitchinterval(0.001)  # and it waits at most ~1 ms per thread that holds the GIL
        yield
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
    for module in (public, submissions, uploads):
        app.include_router(module.router)
    install_pages(app, svc)
    app.add_middleware(CloseUnreadBodies)  # an early answer closes its connection: no unread body is waited for
    return app
