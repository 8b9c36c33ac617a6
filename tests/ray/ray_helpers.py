"""Functions the cluster checks run as Ray tasks (imported by the Ray worker processes)."""
import os
import time

import ray


def slow_square(log_path: str, i: int) -> int:
    """Records (item, node) at its start, takes two seconds, returns i * i."""
    with open(log_path, "a") as log:
        log.write(f"{i} {ray.get_runtime_context().get_node_id()}\n")
        log.flush()
        os.fsync(log.fileno())
    time.sleep(2.0)
    return i * i
