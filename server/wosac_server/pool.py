"""`WorkerPool`: the scoring workers of `wosac-server serve`, started as processes and restarted when they exit.

Only the standard library here: `serve` imports this module, not the scoring stack the workers load
(`wosac_server.worker`), so the API process starts without it.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable

from .supervision import PARENT_PID_FLAG

log = logging.getLogger("wosac_server.worker")


class WorkerPool:
    """Starts `n` worker processes and restarts any that exit until `stop()`."""

    def __init__(self, n: int, env: dict[str, str] | None = None, check_s: float = 0.5):
        self.n = n
        self.env = dict(os.environ if env is None else env)
        self.check_s = check_s
        self.procs: list[subprocess.Popen] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._monitor = threading.Thread(target=self._watch, name="worker-pool", daemon=True)

    def _spawn(self) -> subprocess.Popen:
        # Our pid on its command line: the worker checks it before its slow imports (and arms its
        # parent-death signal), so our death at any moment after this call ends it.
        return subprocess.Popen(
            [sys.executable, "-m", "wosac_server.worker_main", PARENT_PID_FLAG, str(os.getpid())], env=self.env
        )

    def start(self, cancelled: Callable[[], bool] = lambda: False) -> None:
        """Starts the workers one by one, each recorded as soon as it runs, until `cancelled()` (a stop
        requested while `serve` starts); `stop()` then stops every one already started."""
        for _ in range(self.n):
            with self._lock:
                if self._stop.is_set() or cancelled():
                    return
                self.procs.append(self._spawn())
        self._monitor.start()

    def pids(self) -> list[int]:
        with self._lock:
            return [p.pid for p in self.procs]

    def _watch(self) -> None:
        # The workers this thread restarts get their parent-death signal when it ends: only in stop(),
        # which stops them anyway; it must not die of a failed restart, so that is retried.
        while not self._stop.wait(self.check_s):
            with self._lock:
                for i, proc in enumerate(self.procs):
                    code = proc.poll()
                    if code is not None and not self._stop.is_set():
                        log.warning("worker %d exited with %s; starting a new one", proc.pid, code)
                        try:
                            self.procs[i] = self._spawn()
                        except OSError as exc:
                            log.error("could not start a worker (%s); trying again", exc)

    def stop(self, grace_s: float = 10.0) -> None:
        self._stop.set()
        with self._lock:
            procs = list(self.procs)
        for proc in procs:
            if proc.poll() is None:
                proc.terminate()
        deadline = time.monotonic() + grace_s
        for proc in procs:
            try:
                proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
