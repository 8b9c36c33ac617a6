"""The Ray cluster recipe of docs/ray.md with real `ray start` processes (`recipe_checks.py`): a head and a
second node on loopback with Ray 2.60's token authentication, `wosac-eval score --engine ray
--ray-address` giving the local engine's result, one line naming the fix when the client lacks the
token (the CLI and the service), and `ray stop` leaving no process.

In network and PID namespaces of its own (`loopback.run_checks`): only loopback, and `ray stop` sees
only the recipe's processes. Without Ray, root or `unshare` the test skips and says why.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import loopback  # noqa: E402


def test_the_readme_ray_cluster_recipe_with_ray_start_in_a_loopback_namespace():
    print(loopback.run_checks("recipe_checks.py", timeout=900, own_pids=True))
