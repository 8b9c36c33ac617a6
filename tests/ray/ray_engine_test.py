"""The Ray engine: the cluster checks (`cluster_checks.py`) run on a real three-node Ray cluster
inside a network namespace that has only loopback, so no traffic leaves 127.0.0.1.

Ray binds to the machine's interface address; `unshare -n` (as root) gives the
checks a namespace whose only interface is `lo`. Without Ray, root or
`unshare` the test skips and says why.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from support.paths import REPO


def _why_not() -> str | None:
    try:
        import ray  # noqa: F401
    except ImportError:
        return "Ray is not installed (pip install 'wosac-eval[ray]')"
    if os.geteuid() != 0:
        return "the Ray cluster checks need root, to run in a loopback-only network namespace (unshare -n)"
    if not (shutil.which("unshare") and shutil.which("ip")):
        return "unshare and ip (util-linux, iproute2) are needed for a loopback-only network namespace"
    return None


def test_ray_engine_on_a_three_node_cluster_in_a_loopback_namespace():
    reason = _why_not()
    if reason:
        pytest.skip(reason)
    inner = (f"ip link set lo up && exec {sys.executable} -m pytest -q -p no:cacheprovider -x "
             f"-o python_files=cluster_checks.py tests/ray/cluster_checks.py")
    done = subprocess.run(["unshare", "-n", "bash", "-c", inner], cwd=REPO, capture_output=True, text=True,
                          timeout=1500, env={**os.environ, "RAY_DISABLE_USAGE_STATS": "1"})
    summary = "\n".join(done.stdout.splitlines()[-40:]) + "\n" + done.stderr[-3000:]
    assert done.returncode == 0, summary
    assert " passed" in done.stdout and "skipped" not in done.stdout.splitlines()[-1], summary
    print(done.stdout.splitlines()[-1])
