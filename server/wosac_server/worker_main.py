"""A `WorkerPool`'s worker process: `python -m wosac_server.worker_main --parent-pid PID`.

It ties itself to its supervisor before the scoring modules' slow imports: a supervisor that dies
(SIGTERM during its start-up, SIGKILL, OOM) at any moment leaves no worker behind
(`wosac_eval.runtime.processes`). Only the standard library and that module are imported here.
"""

from __future__ import annotations

import signal
import sys

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


def main(argv: list[str] | None = None) -> int:
    parent_pid = parent_pid_argument(sys.argv[1:] if argv is None else argv)
    if parent_pid is not None:
        tie_to_supervisor(parent_pid)
    from wosac_server.worker import main as run_worker  # the slow imports, once tied to the supervisor

    return run_worker(parent_pid)


if __name__ == "__main__":
    sys.exit(main())
