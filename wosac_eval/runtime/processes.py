"""Worker-process pools that stay safe when JAX is loaded.

Forking copies a process with its threads' locks but not the threads; once
JAX has started (it runs thread pools), a forked worker can deadlock. Pools
therefore fork (fast, the default on Linux) unless JAX is loaded in this
process, in which case they spawn fresh interpreters.

A pool's workers end with the process that made them: `ProcessPoolExecutor`
workers whose parent is killed (SIGKILL, the OOM killer, a service stopping a
job) otherwise wait on their queue forever, holding their memory.
"""
from __future__ import annotations

import concurrent.futures as futures
import multiprocessing
import os
import sys
import threading
import time
from collections.abc import Callable


def worker_pool(max_workers: int, *, force_spawn: bool = False, initializer: Callable | None = None,
                initargs: tuple = (), **kwargs) -> futures.ProcessPoolExecutor:
    """A `ProcessPoolExecutor` with a start method that is safe for this process, whose workers end
    when this process does (`initializer(*initargs)` runs in each worker, as in the executor)."""
    spawn = force_spawn or "jax" in sys.modules
    context = multiprocessing.get_context("spawn") if spawn else None
    return futures.ProcessPoolExecutor(max_workers=max_workers, mp_context=context, initializer=_start_worker,
                                       initargs=(os.getpid(), initializer, initargs), **kwargs)


def _start_worker(parent_pid: int, initializer: Callable | None, initargs: tuple) -> None:
    exit_with_parent(parent_pid)
    if initializer is not None:
        initializer(*initargs)


def exit_with_parent(parent_pid: int, poll_s: float = 0.5) -> None:
    """End this process (at once, mid-task) once `parent_pid` is no longer its parent.

    A daemon thread polls the parent's pid: unlike a parent-death signal it does not depend on
    which of the parent's threads started this process, and it works off Linux.
    """
    if os.getppid() != parent_pid:  # the parent died before this process started
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
