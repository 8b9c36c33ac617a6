"""The Ray executor: the same `imap` as `executors.LocalExecutor`, on a Ray cluster.

Joins the cluster at `address` (`host:port` from a node of the cluster,
`ray://host:10001` from outside it), or `RAY_ADDRESS`, or starts a local Ray.
Each item is one Ray task; the shared context is put in the object store once
and deserialised once per worker process. A task whose worker process or node
dies is retried (`MAX_RETRIES` times) by Ray, so losing a node loses no work;
an exception raised by the work itself is not retried: it is raised here as
the original exception (a deterministic failure, e.g. a scenario that cannot
be scored, is reported, not retried forever).
"""
from __future__ import annotations

import collections
import logging
import os
import socket
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import ray

from wosac_eval.runtime.executors import EngineUnavailableError

MAX_RETRIES = 3  # system failures (a dead worker process or node) per task
IN_FLIGHT_PER_CPU = 2

# Worker-process state: shared contexts by object id, and whether the initializer ran.
_CACHE: dict[str, Any] = {}
_INITIALIZED: set = set()


def _shared_value(box: list):
    ref = box[0]
    key = ref.hex()
    if key not in _CACHE:
        _CACHE.clear()  # one context at a time per worker: a new job replaces the old one
        _CACHE[key] = ray.get(ref)
    return _CACHE[key]


@ray.remote(max_retries=MAX_RETRIES, retry_exceptions=False)
def _task(fn: Callable, initializer: Callable | None, box: list, item: Any):
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
        raise EngineUnavailableError(f"{address!r} is not a Ray cluster address (host:port, or "
                                     "ray://host:10001)") from None
    except OSError as error:
        raise EngineUnavailableError(f"cannot reach the Ray cluster at {address}: {error.strerror or error}. "
                                     "Is it up (`ray status` on its head), and is the address the head's "
                                     "host:port (6379 by default, or ray://host:10001 from outside the "
                                     "cluster)?") from None


def connect(address: str | None = None) -> None:
    """Joins the cluster (or starts a local Ray) unless this process is connected already."""
    if ray.is_initialized():
        return
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address:
        _check_reachable(address)
    try:
        # "local", not None: None would join whatever /tmp/ray/ray_current_cluster names, even a
        # cluster that died long ago (Ray then retries for minutes).
        ray.init(address=address or "local", ignore_reinit_error=True, include_dashboard=False,
                 logging_level=logging.ERROR, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError, TimeoutError) as error:
        where = f"the Ray cluster at {address}" if address else "a local Ray"
        raise EngineUnavailableError(f"cannot connect to {where}: {error}. Is the cluster up (`ray status`), "
                                     "and the address host:port of its head (or ray://host:10001)?") from error


class RayExecutor:
    """Ray tasks on the cluster at `address` (see `connect`)."""

    def __init__(self, address: str | None = None, *, initializer: Callable[[], None] | None = None):
        connect(address)
        self.initializer = initializer
        self.parallelism = max(1, int(ray.cluster_resources().get("CPU", 1)))

    def imap(self, fn: Callable[[Any, Any], Any], items: Iterable, shared: Any = None) -> Iterator:
        box = [ray.put(shared)]  # in a list: Ray passes the reference, the worker fetches it once
        pending: collections.deque = collections.deque()
        limit = IN_FLIGHT_PER_CPU * self.parallelism
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


def _result(ref):
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as error:
        cause = getattr(error, "cause", None)  # the work's own exception: raised as if it ran here
        if isinstance(cause, Exception):
            raise cause from None
        raise RuntimeError(f"a Ray task failed: {error}") from None
    except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError,
            ray.exceptions.ObjectLostError) as error:
        raise RuntimeError(f"a Ray task was lost {MAX_RETRIES + 1} times (its worker or node died each "
                           f"time): {error}") from error
