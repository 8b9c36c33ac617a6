"""How a `WorkerPool`'s worker ties itself to the supervisor that started it (`--parent-pid PID`).

The supervisor puts its pid on the worker's command line; the worker reads it and arms its
parent-death signal before anything slow, so a supervisor that dies (SIGTERM during its start-up,
SIGKILL, OOM) at any moment leaves no worker behind (`wosac_eval.runtime.processes`). Only the standard
library and that module are imported here: the pool (in the API process) and the worker's first lines
import this, never the scoring stack.
"""

from __future__ import annotations

import signal

from wosac_eval.runtime.processes import exit_with_parent

PARENT_PID_FLAG = "--parent-pid"


def parent_pid_argument(argv: list[str]) -> int | None:
    """The pid after `--parent-pid` in a worker's arguments (the supervisor that started it), if any."""
    if len(argv) >= 2 and argv[0] == PARENT_PID_FLAG and argv[1].isdigit():
        return int(argv[1])
    return None


def tie_to_supervisor(parent_pid: int) -> None:
    """End this process with its supervisor `parent_pid`, and at once if that is gone already."""
    # SIGTERM: the same graceful stop as from the supervisor (release the job, end its process);
    # before the worker's handler is installed, it simply ends this process.
    exit_with_parent(parent_pid, death_signal=signal.SIGTERM, watch=False)
