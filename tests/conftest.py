"""Fixtures for every test: the reference material in ../shared (or WOSAC_SHARED), when present.

The run fails when a process it started is still alive at its end (after every fixture's teardown
and a short grace period): each is reported by pid and command line, then killed. A run's processes
are its descendants, and every process carrying this run's `PYTEST_WOSAC_EVAL_SESSION` (set below,
inherited by every child) however it was re-parented: orphans adopted by pid 1 or a subreaper, and
daemons such as the PostgreSQL server of tests/server or the processes of a Ray cluster in its
`unshare -n` namespace.
"""
from __future__ import annotations

import os
import signal
import sys
import time
import uuid
from pathlib import Path

import pytest

from support.paths import require_shared
from support.processes import alive, command_line, left_behind

# Not a WOSAC_* name: the service harness passes no WOSAC_* variable of the test run on to a server.
SESSION_MARK = "PYTEST_WOSAC_EVAL_SESSION"
os.environ[SESSION_MARK] = uuid.uuid4().hex  # before any test starts a process: each inherits it
# The test process opts in to exact float32 on XLA's CPU (no fused multiply-adds), as a program does
# with `jax_backend.exact_cpu()`: here before anything can start JAX, and inherited by every child.
if "xla_cpu_max_isa" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_max_isa=AVX".strip()
LEAK_GRACE_S = 5.0
_LEAKS_KEY = pytest.StashKey[list]()


@pytest.fixture
def shared() -> Path:
    return require_shared()


def pytest_collection_modifyitems(config, items):
    """Tests that start JAX run last: JAX runs threads, and later tests fork worker processes."""
    uses_jax = ("jax_backend_test.py", "test_jax_kernels.py", "test_score_backends.py", "jax_realism_test.py",
                "soft_realism_test.py")
    items.sort(key=lambda item: item.path.name in uses_jax)


def _multiprocessing_resource_tracker(pid: int, ppid: int) -> bool:
    """The standard library's resource tracker of this pytest process (started by the first spawned
    pool of a test run in-process): it has no public way to stop it and it ends when this process
    does (its pipe closes). The trackers of other processes are theirs: leaks if they outlive them."""
    return ppid == os.getpid() and "multiprocessing.resource_tracker" in command_line(pid)


@pytest.hookimpl(trylast=True)  # after the runner's own sessionfinish, which tears the last fixtures down
def pytest_sessionfinish(session, exitstatus):
    """Fail the run if a process it started outlives it: report each, then kill it."""
    if not sys.platform.startswith("linux") or hasattr(session.config, "workerinput"):
        return

    def ours() -> dict[int, int]:
        return {pid: ppid for pid, ppid in left_behind(os.getpid(), SESSION_MARK, os.environ[SESSION_MARK]).items()
                if not _multiprocessing_resource_tracker(pid, ppid)}

    deadline = time.monotonic() + LEAK_GRACE_S
    found = ours()
    while found and time.monotonic() < deadline:  # ending already (a worker that saw its server go)
        time.sleep(0.1)
        found = ours()
    if not found:
        return
    leaks = [f"pid {pid} (parent {ppid}): {command_line(pid) or '?'}" for pid, ppid in sorted(found.items())]
    for pid in found:
        try:
            os.kill(pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
    time.sleep(0.5)
    still = [pid for pid in found if alive(pid)]
    if still:
        leaks.append(f"(still alive after SIGKILL: {still})")
    session.config.stash[_LEAKS_KEY] = leaks
    if session.exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    leaks = config.stash.get(_LEAKS_KEY, None)
    if not leaks:
        return
    terminalreporter.section("processes left behind", sep="!", red=True, bold=True)
    count = sum(line.startswith("pid ") for line in leaks)
    terminalreporter.line(f"{count} process(es) started by this test run "
                          f"were still alive {LEAK_GRACE_S:g} s after it ended (all fixtures torn down); "
                          "killed them. The run fails:", red=True)
    for line in leaks:
        terminalreporter.line("  " + line, red=True)
