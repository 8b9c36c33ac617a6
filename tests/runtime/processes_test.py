"""Worker pools fork by default and spawn once JAX is loaded; both run real work."""

import os
import subprocess
import sys
import textwrap
import time

import pytest

from support.processes import alive, processes_with, wait_gone

PROBE = textwrap.dedent("""
    import os, sys
    if sys.argv[1] == "jax":
        import jax
        jax.numpy.zeros(3).block_until_ready()  # start JAX's threads
    from wosac_eval.runtime.processes import worker_pool
    with worker_pool(2) as pool:
        pids = {f.result() for f in [pool.submit(os.getpid) for _ in range(4)]}
        print(pool._mp_context.get_start_method(), os.getpid() not in pids)
""")


def _start_method(mode: str) -> list[str]:
    return subprocess.run(
        [sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True
    ).stdout.split()


@pytest.mark.skipif(sys.platform != "linux", reason="fork is the default start method on Linux only")
def test_forks_without_jax():
    assert _start_method("plain") == ["fork", "True"]


def test_spawns_once_jax_is_loaded():
    pytest.importorskip("jax")
    assert _start_method("jax") == ["spawn", "True"]


ORPHAN_PROBE = textwrap.dedent("""
    import os, signal, sys, time
    from wosac_eval.runtime.processes import worker_pool

    def busy(seconds):
        time.sleep(seconds)
        return os.getpid()

    if __name__ == "__main__":
        pool = worker_pool(2, force_spawn=sys.argv[1] == "spawn")
        pids = {f.result() for f in [pool.submit(busy, 0.1) for _ in range(4)]}
        pool.submit(busy, 60)  # a long task in flight when the parent dies
        print(" ".join(map(str, sorted(pids))), flush=True)
        time.sleep(0.5)
        os.kill(os.getpid(), signal.SIGKILL)
""")


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
@pytest.mark.parametrize("mode", ["fork", "spawn"])
def test_workers_end_with_a_killed_parent(tmp_path, mode):
    """A scorer killed with SIGKILL (the OOM killer, a service stopping a job) leaves no pool worker
    behind, idle or mid-task: a ProcessPoolExecutor's workers would otherwise wait forever."""
    script = tmp_path / "probe.py"
    script.write_text(ORPHAN_PROBE)
    done = subprocess.run([sys.executable, str(script), mode], capture_output=True, text=True, timeout=60)
    assert done.returncode == -9, done.stderr
    pids = [int(p) for p in done.stdout.split()]
    assert pids
    deadline = time.monotonic() + 10
    while any(map(alive, pids)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(map(alive, pids)), [p for p in pids if alive(p)]


KILLED_AT_ONCE_PROBE = textwrap.dedent("""
    import os, signal, sys, time
    from wosac_eval.runtime.processes import worker_pool

    if __name__ == "__main__":
        pool = worker_pool(2, force_spawn=sys.argv[1] == "spawn")
        pool.submit(time.sleep, 60)  # starts the workers...
        os.kill(os.getpid(), signal.SIGKILL)  # ...and dies while they start
""")


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
@pytest.mark.parametrize("mode", ["fork", "spawn"])
def test_workers_of_a_parent_killed_while_they_start_end(tmp_path, mode):
    """The parent dies before its workers are ready (a spawned one is still importing): they end too."""
    script = tmp_path / "probe.py"
    script.write_text(KILLED_AT_ONCE_PROBE)
    marker = ("WOSAC_POOL_PROBE", str(tmp_path))  # found by the environment they inherit
    done = subprocess.run(
        [sys.executable, str(script), mode],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, marker[0]: marker[1]},
    )
    assert done.returncode == -9, done.stderr
    left = wait_gone(processes_with(*marker), 15)
    try:
        assert not left, f"{left} outlived their parent"
    finally:
        for pid in left:
            os.kill(pid, 9)
