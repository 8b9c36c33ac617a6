"""The allocator setting: applied on glibc, opt-out honoured, and page faults really drop."""

import os
import subprocess
import sys
import textwrap

import pytest

glibc_only = pytest.mark.skipif(
    not sys.platform.startswith("linux") or os.confstr("CS_GNU_LIBC_VERSION") is None,
    reason="mallopt thresholds are a glibc feature",
)

# Allocates and frees 2 MiB arrays many times, reporting the minor page faults it took.
PROBE = textwrap.dedent("""
    import resource, sys
    import numpy as np
    from wosac_eval.runtime.allocator import keep_freed_memory
    applied = keep_freed_memory() if sys.argv[1] == "on" else False
    a = np.ones(1 << 19, np.float32)
    start = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(200):
        b = a * 2.0
        c = b + a
        del b, c
    print(applied, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - start)
""")


def _probe(mode, **env):
    out = subprocess.run(
        [sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True, env={**os.environ, **env}
    ).stdout.split()
    return out[0] == "True", int(out[1])


@glibc_only
def test_reused_memory_stops_faulting():
    applied, faults_on = _probe("on")
    assert applied
    _, faults_off = _probe("off")
    # Without the setting each temporary is fresh memory (hundreds of faults per
    # array); with it the freed blocks are reused.
    assert faults_off > 10 * max(faults_on, 100), (faults_on, faults_off)


@glibc_only
def test_opt_out():
    applied, _ = _probe("on", WOSAC_EVAL_SYSTEM_MALLOC="1")
    assert not applied
