"""A `WorkerPool`'s worker process: `python -m wosac_server.worker_main --parent-pid PID`.

It ties itself to its supervisor (`supervision`) before the scoring modules' slow imports, then runs
`wosac_server.worker`. Nothing imports this module: it is the worker's entry point alone.
"""

from __future__ import annotations

import sys

from wosac_server.supervision import parent_pid_argument, tie_to_supervisor


def main(argv: list[str] | None = None) -> int:
    parent_pid = parent_pid_argument(sys.argv[1:] if argv is None else argv)
    if parent_pid is not None:
        tie_to_supervisor(parent_pid)
    # Imported only now, once tied: the scoring stack takes seconds to import, and a supervisor that died
    # meanwhile must not leave this process behind.
    from wosac_server.worker import main as run_worker

    return run_worker(parent_pid)


if __name__ == "__main__":
    sys.exit(main())
