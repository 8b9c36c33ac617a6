"""Worker pools fork by default and spawn once JAX is loaded; both run real work."""
import subprocess
import sys
import textwrap

import pytest

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
    return subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True,
                          check=True).stdout.split()


@pytest.mark.skipif(sys.platform != "linux", reason="fork is the default start method on Linux only")
def test_forks_without_jax():
    assert _start_method("plain") == ["fork", "True"]


def test_spawns_once_jax_is_loaded():
    pytest.importorskip("jax")
    assert _start_method("jax") == ["spawn", "True"]
