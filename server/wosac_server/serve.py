"""`wosac-server serve`: run the HTTP scoring service (API + scoring worker processes).

Configured by `WOSAC_*` environment variables (see `wosac_server.settings`);
the flags below override the most common ones. Exit codes: 0 stopped cleanly
(SIGTERM or SIGINT included, at any moment), 2 the configuration is unusable
(no scenario shard found, bad value).

SIGTERM (or SIGINT) stops the service at any moment of its life: during its
start-up too (it is recorded and honoured at the next step; the workers already
started are stopped, none is left behind), and after uvicorn's graceful shutdown
the workers are stopped before the process exits.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported where used: `--help` stays fast
    import uvicorn

    from .settings import Settings

NAME = "serve"
HELP = "Run the HTTP scoring service (upload submissions, follow scoring, leaderboard)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--host",
        default=os.environ.get("WOSAC_HOST", "127.0.0.1"),
        help="address to listen on (default 127.0.0.1; WOSAC_HOST)",
    )
    parser.add_argument(
        "--port",
        type=int,
        default=int(os.environ.get("WOSAC_PORT", "8000")),
        help="TCP port (default 8000; WOSAC_PORT)",
    )
    parser.add_argument("--scenarios", help="scenario shards, comma-separated paths or globs (WOSAC_SCENARIOS)")
    parser.add_argument("--data-dir", help="uploads, results, SQLite file (WOSAC_DATA_DIR)")
    parser.add_argument("--workers", type=int, help="scoring worker processes (WOSAC_WORKERS)")
    parser.add_argument("--log-level", default="info", choices=("debug", "info", "warning", "error"))


def raise_open_files_limit() -> None:
    """Use the hard limit of open files: each connection is one (the per-client cap keeps one client
    from taking them all)."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and soft < hard:
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))


def proxy_options(settings: Settings) -> dict:
    """uvicorn's proxy options: forwarded headers are believed only from the configured proxies (uvicorn
    alone would believe them from 127.0.0.1, so any local process could pose as any address)."""
    trusted = ",".join(p.strip() for p in settings.trusted_proxies.split(",") if p.strip())
    return {"proxy_headers": bool(trusted), "forwarded_allow_ips": trusted or None}


class StopRequest:
    """The SIGTERM/SIGINT handler of `serve` outside uvicorn's own: it records the request and tells the
    uvicorn server, once there is one, to shut down; start-up looks at it between its steps.

    Why not raise from the handler: an exception raised at an arbitrary instant is swallowed by any
    broad `except` it lands in (a logging handler, an asyncio callback, uvicorn's lifespan probe), and
    the service then ran on as if never stopped."""

    def __init__(self) -> None:
        self.requested = False
        self.server: uvicorn.Server | None = None  # once made

    def __call__(self, signum, frame) -> None:
        self.requested = True
        if self.server is not None:
            self.server.should_exit = True  # what uvicorn's own handler does


def run(args: argparse.Namespace) -> int:
    # Before any worker exists: from here on a stop request is honoured between start-up steps and
    # the workers are stopped in `_run`'s `finally` (the default action would end this process at
    # once and leave them to find out on their own). uvicorn replaces these handlers while it serves,
    # then puts them back and raises the signal it got again, which lands here.
    stop = StopRequest()
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    return _run(args, stop)


def _run(args: argparse.Namespace, stop: StopRequest) -> int:
    # Flags become environment so the worker processes see the same configuration.
    for flag, var in (("scenarios", "WOSAC_SCENARIOS"), ("data_dir", "WOSAC_DATA_DIR"), ("workers", "WOSAC_WORKERS")):
        value = getattr(args, flag)
        if value is not None:
            os.environ[var] = str(value)

    from pydantic import ValidationError

    from .settings import load_settings

    try:
        settings = load_settings()
    except ValidationError as exc:
        print(f"wosac-server serve: bad configuration:\n{exc}", file=sys.stderr)
        return 2
    scenarios = settings.scenario_paths()
    if not scenarios:
        print(
            "wosac-server serve: no scenario shard found; set WOSAC_SCENARIOS (or --scenarios) to the "
            f"TFRecord files to score against (got {settings.scenarios or 'nothing'})",
            file=sys.stderr,
        )
        return 2
    os.environ["WOSAC_DATA_DIR"] = str(settings.data_dir)

    if stop.requested:
        return 0
    import uvicorn

    from . import jobs
    from .app import create_app
    from .guard import accept_backlog, guarded_protocol, install_log_limits
    from .pool import WorkerPool

    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(name)s %(levelname)s %(message)s")
    app = create_app(settings)
    # Jobs left running by a previous server that died go back to the queue at once.
    jobs.reap_expired(app.state.store, settings.max_attempts)
    if stop.requested:
        return 0
    print(
        f"wosac-server serve: {len(scenarios)} scenario shard(s), data in {settings.data_dir}, "
        f"{settings.workers} worker(s), http://{args.host}:{args.port}/",
        file=sys.stderr,
        flush=True,
    )
    pool = WorkerPool(settings.workers)
    app.state.worker_pool = pool
    try:
        pool.start(cancelled=lambda: stop.requested)
        raise_open_files_limit()
        config = uvicorn.Config(
            app,
            host=args.host,
            port=args.port,
            log_level=args.log_level,
            timeout_graceful_shutdown=int(settings.shutdown_grace_s) or 1,
            http=guarded_protocol(settings),
            **proxy_options(settings),
            backlog=accept_backlog(),
        )  # accepted at once: fits the cap's spare descriptors
        install_log_limits()  # after uvicorn.Config, which installs uvicorn's log handlers
        server = uvicorn.Server(config)
        stop.server = server  # a request from here on reaches uvicorn, even before it takes the signals
        if not stop.requested:
            server.run()
    finally:
        # Stopping is bounded (grace, then SIGKILL); a second SIGTERM meanwhile only records itself.
        pool.stop(grace_s=settings.shutdown_grace_s)
    return 0
