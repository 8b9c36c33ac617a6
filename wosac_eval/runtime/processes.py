"""Worker-process pools that stay safe when JAX is loaded.

Forking copies a process with its threads' locks but not the threads; once
JAX has started (it runs thread pools), a forked worker can deadlock. Pools
therefore fork (fast, the default on Linux) unless JAX is loaded in this
process, in which case they spawn fresh interpreters.
"""
from __future__ import annotations

import concurrent.futures as futures
import multiprocessing
import sys


def worker_pool(max_workers: int, *, force_spawn: bool = False, **kwargs) -> futures.ProcessPoolExecutor:
    """A `ProcessPoolExecutor` with a start method that is safe for this process."""
    spawn = force_spawn or "jax" in sys.modules
    context = multiprocessing.get_context("spawn") if spawn else None
    return futures.ProcessPoolExecutor(max_workers=max_workers, mp_context=context, **kwargs)
