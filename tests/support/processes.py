"""Which processes live, read from Linux /proc: for the tests that kill scorers and workers and check
that nothing is left behind."""

from __future__ import annotations

import os
import time

# Ray's settings for every Ray process the tests start (the loopback checks, the documents' Ray blocks): no
# usage stats sent, and the workers at nice 0. Ray starts its workers at nice 15 (its `worker_niceness`): beside
# CI's other tests on two cores they got a few per cent of a core, and a scoring run of minutes passed its
# 10-minute limit (twice on 2026-12-07, `test_cli_without_address_starts_a_local_ray`, the workers' logs showing
# them alive and slowly working). At nice 0 they share the cores as the tests' other processes do.
RAY_TEST_ENV = {"RAY_DISABLE_USAGE_STATS": "1", "RAY_worker_niceness": "0"}


def _status(pid: int | str) -> dict[str, str]:
    """The fields of /proc/<pid>/status (State, PPid...); empty when the process is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return dict(line.split(":\t", 1) for line in f.read().splitlines() if ":\t" in line)
    except (FileNotFoundError, ProcessLookupError):
        return {}


def _running(status: dict[str, str]) -> bool:
    return status.get("State", "Z").split()[0] != "Z"  # gone, or a zombie waiting to be reaped: ended


def alive(pid: int) -> bool:
    """Running (not gone, not a zombie waiting to be reaped)."""
    return _running(_status(pid))


def environment(pid: int | str) -> dict[str, str]:
    """The environment `pid` was started with (/proc/<pid>/environ); empty when it is gone or not ours
    to read."""
    try:
        with open(f"/proc/{pid}/environ", "rb") as f:
            raw = f.read()
    except OSError:
        return {}
    pairs = (item.split(b"=", 1) for item in raw.split(b"\0") if b"=" in item)
    return {k.decode(errors="replace"): v.decode(errors="replace") for k, v in pairs}


def command_line(pid: int | str) -> str:
    """What `pid` runs, as ps would show it ("" when it is gone)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().rstrip(b"\0").replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def processes_with(name: str, value: str) -> dict[int, int]:
    """{pid: parent pid} of the live processes started with `name=value` in their environment (which
    children inherit: everything started for one test, one server, one test session)."""
    marker = f"{name}={value}".encode()
    found = {}
    for entry in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{entry}/environ", "rb") as f:
                ours = marker in f.read().split(b"\0")
        except OSError:  # gone, or not ours to read
            continue
        status = _status(entry) if ours else {}
        if _running(status):
            found[int(entry)] = int(status["PPid"])
    return found


def processes_of(data_dir) -> dict[int, int]:
    """{pid: parent pid} of the live processes started for a server's data dir (by their environment)."""
    return processes_with("WOSAC_DATA_DIR", str(data_dir))


def descendants(*pids: int) -> dict[int, int]:
    """{pid: parent pid} of the live descendants of `pids` (children, their children...)."""
    parents = {}
    for entry in filter(str.isdigit, os.listdir("/proc")):
        status = _status(entry)
        if _running(status):
            parents[int(entry)] = int(status["PPid"])
    found, frontier = {}, set(pids)
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier and child not in found}
        found.update((child, parents[child]) for child in frontier)
    return found


def wait_gone(pids, timeout: float) -> list[int]:
    """Waits up to `timeout` s for every pid of `pids` to end; the ones still running."""
    deadline = time.monotonic() + timeout
    left = [p for p in pids if alive(p)]
    while left and time.monotonic() < deadline:
        time.sleep(0.05)
        left = [p for p in left if alive(p)]
    return left


def left_behind(root: int, name: str, value: str) -> dict[int, int]:
    """{pid: parent pid} of the live processes of a test run: the descendants of `root` (its pid), the
    processes started with `name=value` in their environment wherever they are now (re-parented to pid 1
    or to a subreaper once their parent died, or started by a daemon such as `pg_ctl`'s server), and
    the descendants of those (a PostgreSQL server's children overwrite their environment)."""
    marked = processes_with(name, value)
    found = {**marked, **descendants(root, *marked)}
    found.pop(root, None)
    found.pop(os.getpid(), None)
    return found
