"""The Ray executor: the same `imap` as `executors.LocalExecutor`, on a Ray cluster.

Joins the cluster at `address` (`host:port` from a node of the cluster,
`ray://host:10001` from outside it), or `RAY_ADDRESS`, or starts a local Ray.
Each item is one Ray task; the shared context is put in the object store once
and deserialised once per worker process. A task whose worker process or node
dies is retried (`MAX_RETRIES` times) by Ray, so losing a node loses no work;
an exception raised by the work itself is not retried: it is raised here as
the original exception (a deterministic failure, e.g. a scenario that cannot
be scored, is reported, not retried forever).

A cluster with token authentication (since Ray 2.60 `ray start --head` turns it on
when a token exists, e.g. the `~/.ray/auth_token` that any earlier local
`ray.init()` writes) is joined with Ray's documented variables: RAY_AUTH_MODE=token
and the cluster's token in RAY_AUTH_TOKEN, in the file RAY_AUTH_TOKEN_PATH names,
or in ~/.ray/auth_token. Without them Ray sends no token to an explicit address and
retries for 20 s, logging a line per try (a Ray Client, ray://, just times out
after 30 s); `connect` keeps those lines and says in one sentence what to set
instead (`_auth_advice`, `_client_advice`).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import re
import socket
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import ray

from wosac_eval.extras import EngineAuthenticationError, EngineUnavailableError

MAX_RETRIES = 3  # system failures (a dead worker process or node) per task
IN_FLIGHT_PER_CPU = 2

# Worker-process state: shared contexts by object id, and whether the initializer ran.
_CACHE: dict[str, Any] = {}
_INITIALIZED: set = set()


def _shared_value(box: list) -> Any:
    ref = box[0]
    key = ref.hex()
    if key not in _CACHE:
        _CACHE.clear()  # one context at a time per worker: a new job replaces the old one
        _CACHE[key] = ray.get(ref)
    return _CACHE[key]


@ray.remote(max_retries=MAX_RETRIES, retry_exceptions=False)
def _task(fn: Callable, initializer: Callable | None, box: list, item: Any) -> Any:
    if initializer is not None and initializer not in _INITIALIZED:
        initializer()
        _INITIALIZED.add(initializer)
    return fn(_shared_value(box), item)


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fails fast when nothing listens at a `host:port` (Ray itself would keep retrying for minutes)."""
    if address == "auto":
        return
    host, _, port = address.split("://")[-1].rpartition(":")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout_s):
            pass
    except ValueError:
        raise EngineUnavailableError(
            f"{address!r} is not a Ray cluster address (host:port, or ray://host:10001)"
        ) from None
    except OSError as error:
        raise EngineUnavailableError(
            f"cannot reach the Ray cluster at {address}: {error.strerror or error}. "
            "Is it up (`ray status` on its head), and is the address the head's "
            "host:port (6379 by default, or ray://host:10001 from outside the "
            "cluster)?"
        ) from None


AUTH_MODE, AUTH_TOKEN, AUTH_TOKEN_PATH = "RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH"
_RAY_LOG_LINE = re.compile(r"^\[\d{4}-\d\d-\d\d [\d:,.]+ [A-Z] \d+ \d+\] ")  # Ray's C++ log format


def _token_source() -> str:
    """Where Ray reads this process's token from, in Ray's order (its token-auth documentation)."""
    if os.environ.get(AUTH_TOKEN):
        return AUTH_TOKEN
    if os.environ.get(AUTH_TOKEN_PATH):
        return f"the file {os.environ[AUTH_TOKEN_PATH]} ({AUTH_TOKEN_PATH})"
    return str(Path.home() / ".ray" / "auth_token")


def _give_token() -> str:
    return (
        f"give the cluster's token (`ray get-auth-token` on its head) in {AUTH_TOKEN}, in a file named by "
        f"{AUTH_TOKEN_PATH}, or in {Path.home() / '.ray' / 'auth_token'}"
    )


def _mode_unset() -> bool:
    return os.environ.get(AUTH_MODE, "").lower() != "token"


def _set_mode() -> str:
    ignored = (
        f" ({AUTH_TOKEN}/{AUTH_TOKEN_PATH} are ignored without it)"
        if os.environ.get(AUTH_TOKEN) or os.environ.get(AUTH_TOKEN_PATH)
        else ""
    )
    return f"set {AUTH_MODE}=token{ignored} and {_give_token()}"


def _auth_advice(where: str, token_found: bool) -> str:
    """One sentence: the cluster wants a token, and how to give it the right one."""
    if _mode_unset():
        return f"{where} requires token authentication and this process sent no token: {_set_mode()}"
    if not token_found:
        return f"{where} requires token authentication but {AUTH_MODE}=token found no token: {_give_token()}"
    return f"{where} rejected the authentication token from {_token_source()}: {_give_token()}"


def _client_advice(where: str, error: Exception) -> str:
    """A Ray Client (ray://) turned away for want of the token only times out: one sentence saying so."""
    if _mode_unset():
        fix = f"if it requires token authentication (Ray turns it on when the head has a token), {_set_mode()}"
    else:
        fix = (
            f"if it requires token authentication, is the token from {_token_source()} the cluster's "
            "(`ray get-auth-token` on its head)?"
        )
    return f"cannot connect to {where} ({error}) although its port answers: {fix}"


@contextlib.contextmanager
def _stderr_kept(keep: list) -> Any:
    """Collects what this process writes to file descriptor 2 (Ray's C++ logging included) into `keep`."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            keep.append(sink.read().decode(errors="replace"))


def connect(address: str | None = None) -> None:
    """Joins the cluster (or starts a local Ray) unless this process is connected already."""
    if ray.is_initialized():
        return
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address:
        _check_reachable(address)
    where = f"the Ray cluster at {address}" if address else "a local Ray"
    logged: list[str] = []
    # Only when joining a running cluster: a local Ray's processes, started here, inherit descriptor 2.
    kept = _stderr_kept(logged) if address else contextlib.nullcontext()
    try:
        with kept, warnings.catch_warnings():
            # Said better below, in the error, when it applies.
            warnings.filterwarnings("ignore", "Ray Client connection timed out", UserWarning)
            # "local", not None: None would join whatever /tmp/ray/ray_current_cluster names, even a
            # cluster that died long ago (Ray then retries for minutes).
            _init_with_retries(address)
    except ray.exceptions.AuthenticationError as error:  # RAY_AUTH_MODE=token: no token, or a rejected one
        _replay(logged, drop_ray_log=True)
        raise EngineAuthenticationError(_auth_advice(where, "no authentication token" not in str(error))) from None
    except (ConnectionError, RuntimeError, ValueError, TimeoutError) as error:
        if "InvalidAuthToken" in "".join(logged):  # the head turned the token away on every try
            _replay(logged, drop_ray_log=True)
            raise EngineAuthenticationError(_auth_advice(where, True)) from None
        _replay(logged)
        if address and address.startswith("ray://") and "timeout" in str(error):
            raise EngineUnavailableError(_client_advice(where, error)) from None
        raise EngineUnavailableError(
            f"cannot connect to {where}: {error}. Is the cluster up (`ray status`), "
            "and the address host:port of its head (or ray://host:10001)?"
        ) from error
    _replay(logged)


# A Ray Client connection whose server-side process failed to start ("Initialization failure from
# server": Ray's proxy can find the process it polls already exited, a race of its own) is the
# server's passing fault, not a wrong address or token: tried again, after a pause, this many times.
# Ray reports it only after its log-stream proxy's wait for that process (the head's
# RAY_CLIENT_SERVER_CHECK_CHANNEL_TIMEOUT_S, 30 s by default; a head with more holds us as long).
CLIENT_START_ATTEMPTS = 3
_CLIENT_START_PAUSE_S = 1.0


def _init_with_retries(address: str | None) -> None:
    for attempt in range(1, CLIENT_START_ATTEMPTS + 1):
        try:
            ray.init(
                address=address or "local",
                ignore_reinit_error=True,
                include_dashboard=False,
                logging_level=logging.ERROR,
                log_to_driver=False,
            )
            return
        except ConnectionError as error:
            passing = (
                address is not None
                and address.startswith("ray://")
                and "Initialization failure from server" in str(error)
            )
            if not passing or attempt == CLIENT_START_ATTEMPTS:
                raise
            ray.shutdown()
            time.sleep(_CLIENT_START_PAUSE_S)


def _replay(logged: list[str], drop_ray_log: bool = False) -> None:
    """Writes the collected stderr back; `drop_ray_log`: without Ray's own log lines (a failed connection's)."""
    text = "".join(logged)
    if drop_ray_log:
        text = "".join(line for line in text.splitlines(keepends=True) if not _RAY_LOG_LINE.match(line))
    if text:
        sys.stderr.write(text)
        sys.stderr.flush()


class RayExecutor:
    """Ray tasks on the cluster at `address` (see `connect`)."""

    def __init__(self, address: str | None = None, *, initializer: Callable[[], object] | None = None) -> None:
        connect(address)
        self.initializer = initializer
        self.parallelism = max(1, int(ray.cluster_resources().get("CPU", 1)))

    def imap(
        self, fn: Callable[[Any, Any], Any], items: Iterable, shared: Any = None, *, ahead: int | None = None
    ) -> Iterator:
        box = [ray.put(shared)]  # in a list: Ray passes the reference, the worker fetches it once
        pending: collections.deque = collections.deque()
        limit = IN_FLIGHT_PER_CPU * self.parallelism if ahead is None else self.parallelism + ahead
        try:
            for item in items:
                pending.append(_task.remote(fn, self.initializer, box, item))
                while len(pending) > limit:
                    yield _result(pending.popleft())
            while pending:
                yield _result(pending.popleft())
        finally:
            for ref in pending:  # the caller stopped early (an error, an interrupted run)
                ray.cancel(ref)


def _result(ref: Any) -> Any:
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as error:
        cause = getattr(error, "cause", None)  # the work's own exception: raised as if it ran here
        if isinstance(cause, Exception):
            raise cause from None
        raise RuntimeError(f"a Ray task failed: {error}") from None
    except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError, ray.exceptions.ObjectLostError) as error:
        raise RuntimeError(
            f"a Ray task was lost {MAX_RETRIES + 1} times (its worker or node died each time): {error}"
        ) from error
