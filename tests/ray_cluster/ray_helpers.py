"""Functions the cluster checks run as Ray tasks (imported by the Ray worker processes)."""

import os
import time

import ray

HOLD_LIMIT_S = 900  # an item released by nobody (the check crashed) ends anyway


def release_path(log_path: str) -> str:
    """The file whose existence releases the items of `held_square`."""
    return log_path + ".release"


def held_square(log_path: str, i: int) -> int:
    """Records (item, node, worker process) at its start, holds until `release_path(log_path)` exists,
    returns i * i."""
    with open(log_path, "a") as log:
        log.write(f"{i} {ray.get_runtime_context().get_node_id()} {os.getpid()}\n")
        log.flush()
        os.fsync(log.fileno())
    deadline = time.monotonic() + HOLD_LIMIT_S
    while not os.path.exists(release_path(log_path)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return i * i
