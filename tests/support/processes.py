"""Which processes live, read from Linux /proc: for the tests that kill scorers and workers and check
that nothing is left behind."""
from __future__ import annotations

import os


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


def processes_of(data_dir) -> dict[int, int]:
    """{pid: parent pid} of the live processes started for a server's data dir (by their environment)."""
    marker = f"WOSAC_DATA_DIR={data_dir}".encode()
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
