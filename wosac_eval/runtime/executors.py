"""Where work runs: this process, worker processes of this host, or a Ray cluster.

Every stage that fans out (indexing scenario files, checking shards, scoring
chunks) is written once as a module-level function `fn(shared, item)` and run
through an executor's `imap`, which yields the results in the order of the
items, whatever the order in which they finish, with a bounded number in
flight (memory stays bounded however large the submission). `shared` is the
read-only context of every item (the scenario index, the config): sent once
per worker process, not once per item.

- `LocalExecutor(workers)`: in this process (`workers <= 1`), or a pool of
  processes (forked, or spawned once JAX is loaded: `processes.worker_pool`).
- `RayExecutor(address)`: Ray tasks on a cluster (`ray_executor`, the `ray`
  extra); a task lost with its worker or node is retried.
"""

from __future__ import annotations

import collections
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Protocol

from wosac_eval.extras import check_engine
from wosac_eval.options import Engine
from wosac_eval.runtime.processes import worker_pool


class Executor(Protocol):
    parallelism: int

    def imap(
        self, fn: Callable[[Any, Any], Any], items: Iterable, shared: Any = None, *, ahead: int | None = None
    ) -> Iterator:
        """`fn(shared, item)` for every item, results in item order.

        `ahead`: how many items may wait, submitted, beyond one per worker (default: the executor's
        own, about one per worker); items that carry a whole shard's bytes ask for 0, so that memory
        holds a shard per worker and not twice that."""


# Worker-process state of the local pool: the shared context, set once per process.
_SHARED: dict[str, Any] = {}


def _init_local_worker(shared: Any, initializer: Callable[[], object] | None) -> None:
    _SHARED["value"] = shared
    if initializer is not None:
        initializer()


def _call_local(fn: Callable, item: Any) -> Any:
    return fn(_SHARED["value"], item)


class LocalExecutor:
    """This process (`workers <= 1`) or `workers` processes of this host.

    Args:
      workers: processes, at least 1 (ValueError otherwise); 1 runs everything in the calling process.
      force_spawn: start fresh interpreters instead of forking (JAX work).
      initializer: called once in every worker process (e.g. the allocator settings).
      warm_up: called once in this process, before its first pool of workers starts: what each
        worker would otherwise do itself, all at once (numba's loops: on a fresh installation every
        worker compiled them; forked workers inherit them, spawned ones read the cache it wrote).
    """

    def __init__(
        self,
        workers: int = 1,
        *,
        force_spawn: bool = False,
        initializer: Callable[[], object] | None = None,
        warm_up: Callable[[], object] | None = None,
    ) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            # Refused, not raised to 1: a caller's 0 or -1 is a mistake to name, not a count to guess.
            raise ValueError(f"workers must be a whole number >= 1, not {workers!r}")
        self.workers = workers
        self.parallelism = self.workers
        self.force_spawn = force_spawn
        self.initializer = initializer
        self.warm_up = warm_up

    def imap(
        self, fn: Callable[[Any, Any], Any], items: Iterable, shared: Any = None, *, ahead: int | None = None
    ) -> Iterator:
        if self.workers <= 1:
            if self.initializer is not None:
                self.initializer()
            for item in items:
                result = fn(shared, item)
                del item  # hold no item (a shard's bytes) while the next one is read
                yield result
            return
        if self.warm_up is not None:
            self.warm_up()
            self.warm_up = None  # once
        with worker_pool(
            self.workers,
            force_spawn=self.force_spawn,
            initializer=_init_local_worker,
            initargs=(shared, self.initializer),
        ) as pool:
            pending: collections.deque = collections.deque()
            for item in items:
                pending.append(pool.submit(_call_local, fn, item))
                while len(pending) > self.workers + (self.workers if ahead is None else ahead):
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()


def make_executor(
    engine: Engine | str = Engine.LOCAL,
    *,
    workers: int = 1,
    ray_address: str | None = None,
    force_spawn: bool = False,
    initializer: Callable[[], object] | None = None,
    warm_up: Callable[[], object] | None = None,
) -> Executor:
    """The executor of an engine (`extras.ENGINES`); raises `extras.EngineUnavailableError` when it cannot run.
    `warm_up`: a local pool's (`LocalExecutor`); a Ray cluster's workers start on their own nodes."""
    if check_engine(engine) is Engine.LOCAL:
        return LocalExecutor(workers, force_spawn=force_spawn, initializer=initializer, warm_up=warm_up)
    from wosac_eval.runtime.ray_executor import RayExecutor  # the ray extra, loaded for the Ray engine alone

    return RayExecutor(ray_address, initializer=initializer)
