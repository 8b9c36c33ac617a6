"""Worker-process pools that stay safe when JAX is loaded.

Forking copies a process with its threads' locks but not the threads; once
JAX has started (it runs thread pools), a forked worker can deadlock. Pools
therefore fork (fast, the default on Linux) unless JAX is loaded in this
process, in which case they spawn fresh interpreters.

A pool's workers end with the process that made them: `ProcessPoolExecutor`
workers whose parent is killed (SIGKILL, the OOM killer, a service stopping a
job) otherwise wait on their queue forever, holding their memory.

Every process the project starts ends with its parent, at any moment of its
life, start-up included: the parent passes its own pid to the child (pool
initializer arguments, a worker's command line, a forked child's copy of the
variable), and the child's first act is `exit_with_parent(that pid)`. A child
that instead read `os.getppid()` once it had imported its modules would, if
the parent died meanwhile, record pid 1 (or a subreaper) as its parent and
live on forever.

This module is imported first thing by processes that must check their parent
before their slow imports: it imports only the standard library.
"""

from __future__ import annotations

import concurrent.futures as futures
import multiprocessing
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import Any


def worker_pool(
    max_workers: int,
    *,
    force_spawn: bool = False,
    initializer: Callable | None = None,
    initargs: tuple = (),
    **kwargs: Any,
) -> futures.ProcessPoolExecutor:
    """A `ProcessPoolExecutor` with a start method that is safe for this process, whose workers end
    when this process does (`initializer(*initargs)` runs in each worker, as in the executor)."""
    spawn = force_spawn or "jax" in sys.modules
    context = multiprocessing.get_context("spawn") if spawn else None
    return futures.ProcessPoolExecutor(
        max_workers=max_workers,
        mp_context=context,
        initializer=_start_worker,
        initargs=(os.getpid(), initializer, initargs),
        **kwargs,
    )


def _start_worker(parent_pid: int, initializer: Callable | None, initargs: tuple) -> None:
    # The pool's first code in the worker: a fork runs it at once, a spawned interpreter once it has
    # imported the parent's main module; a parent gone by then is seen, since its pid came with the
    # arguments. No parent-death signal: the executor starts workers from whichever thread submits (or
    # from its own manager thread), and that thread's end would kill them.
    exit_with_parent(parent_pid)
    if initializer is not None:
        initializer(*initargs)


PR_SET_PDEATHSIG = 1  # prctl(2): a signal for this process when its parent ends


def set_parent_death_signal(sig: int) -> bool:
    """Have Linux send `sig` to this process when its parent ends (prctl PR_SET_PDEATHSIG, through the
    public C library); False where that is not available.

    The signal comes when the *thread* of the parent that started this process ends, and only for a
    death after this call: call `exit_with_parent` right after it (which compares the parent with the pid
    it was given), and use it only for processes started by a thread that lives as long as the parent
    (or whose end should end them too).
    """
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        return ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def exit_with_parent(
    parent_pid: int, poll_s: float = 0.5, *, death_signal: int | None = None, watch: bool = True
) -> None:
    """End this process (at once, mid-task) once `parent_pid` is no longer its parent.

    `parent_pid` comes from the parent itself (never this process's `os.getppid()`, which is already
    pid 1 or a subreaper when the parent died first): a parent that died at any moment since this
    process was started is seen here. `death_signal`: first arm the Linux parent-death signal with it
    (see `set_parent_death_signal`), so that a later death ends this process at once, even while it is
    busy importing or blocked in C code. `watch`: also start a daemon thread that polls the parent's pid
    every `poll_s` seconds: unlike the signal it does not depend on which of the parent's threads
    started this process, and it works off Linux.
    """
    if death_signal is not None:
        set_parent_death_signal(death_signal)
    if os.getppid() != parent_pid:  # the parent died before this process could watch it
        os._exit(1)
    if not watch:
        return

    def watch_parent() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch_parent, name="exit-with-parent", daemon=True).start()
