"""A local executor's warm-up runs once, in this process, before its first pool: the workers start with it done."""

import json
import subprocess
import sys
import textwrap

import pytest

from wosac_eval.runtime.executors import LocalExecutor, make_executor

# Forked workers of a script can run its own functions; the warm-up compiles numba's wire walks (as
# `validate_submission` asks), and each worker says how many of their signatures it finds compiled.
PROBE = textwrap.dedent("""
    import json, os, sys
    import numba
    from wosac_eval.parse import wire_walks
    from wosac_eval.runtime.executors import LocalExecutor

    calls = []

    def warm_up():
        calls.append(os.getpid())
        wire_walks.compile_walks()

    def compiled_here(shared, item):
        walks = [v for v in vars(wire_walks).values() if isinstance(v, numba.core.dispatcher.Dispatcher)]
        return os.getpid(), sum(len(walk.signatures) for walk in walks)

    executor = LocalExecutor(int(sys.argv[1]), warm_up=warm_up)
    first = list(executor.imap(compiled_here, range(4)))
    second = list(executor.imap(compiled_here, range(2)))
    print(json.dumps({"parent": os.getpid(), "calls": calls, "runs": [first, second]}))
""")


def _probe(workers: int, folder) -> dict:
    # (not run in the repository: `-c` imports from its working folder, the tree beside the installed package)
    output = subprocess.run(
        [sys.executable, "-c", PROBE, str(workers)], capture_output=True, text=True, check=True, cwd=folder
    )
    return json.loads(output.stdout)


def test_a_pools_warm_up_runs_once_in_this_process_and_its_workers_start_with_it_done(tmp_path):
    seen = _probe(2, tmp_path)
    assert seen["calls"] == [seen["parent"]]  # once, here, for both pools
    for run in seen["runs"]:
        pids = {pid for pid, _ in run}
        assert seen["parent"] not in pids
        compiled = {count for _, count in run}
        assert len(compiled) == 1 and compiled.pop() > 0  # every worker found the walks compiled


def test_without_workers_there_is_no_warm_up(tmp_path):
    seen = _probe(1, tmp_path)
    assert seen["calls"] == []  # the work runs here and compiles what it calls, as it always did
    assert {pid for run in seen["runs"] for pid, _ in run} == {seen["parent"]}


def test_a_worker_count_under_one_is_refused_not_raised_to_one():
    """`--workers` refuses such a count at the command line; a library caller's gets the same answer."""
    for bad in (0, -2, 1.5, True):
        with pytest.raises(ValueError, match=rf"workers must be a whole number >= 1, not {bad!r}"):
            LocalExecutor(bad)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="workers must be a whole number >= 1"):
            make_executor("local", workers=bad)  # type: ignore[arg-type]
    assert LocalExecutor(3).parallelism == 3
