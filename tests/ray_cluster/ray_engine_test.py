"""The Ray engine: the cluster checks (`cluster_checks.py`) run on a real three-node Ray cluster
inside a network namespace that has only loopback, so no traffic leaves 127.0.0.1, and a PID
namespace of their own, so no Ray process outlives them, even after a timeout (`loopback.py`).

Ray binds to the machine's interface address; `unshare -n` (as root) gives the
checks a namespace whose only interface is `lo`. Without Ray, root or
`unshare` the test skips and says why.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import loopback  # noqa: E402


def test_ray_engine_on_a_three_node_cluster_in_a_loopback_namespace():
    print(loopback.run_checks("cluster_checks.py", timeout=1500, own_pids=True))
