"""Running a module of Ray checks inside a network namespace that has only loopback.

Ray binds to the machine's interface address; `unshare -n` (as root) gives the
checks a namespace whose only interface is `lo`, so no traffic leaves 127.0.0.1.
With `own_pids`, the checks also get a PID namespace of their own (`unshare -p
--mount-proc`): `ray stop` kills every Ray process it can see, so in there it
sees, and stops, only the checks' own; and when the namespace's first process
ends (with `unshare`, `--kill-child`: also when the timeout kills it), the kernel
ends whatever is left in it, so no Ray process outlives the checks.
Without Ray, root or `unshare`, the calling test skips and says why.
"""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import tempfile

import pytest

from support.paths import REPO
from support.processes import RAY_TEST_ENV
from support.runs import console_script

# The checks' pytest, the installed script: `python -m pytest` run in the repository would import this tree
# beside the installed package.
PYTEST = console_script("pytest", "pytest")


def why_not() -> str | None:
    """Why the checks cannot run here, or None."""
    try:
        import ray  # noqa: F401
    except ImportError:
        return "Ray is not installed (pip install 'wosac-eval[ray]')"
    if os.geteuid() != 0:
        return "the Ray cluster checks need root, to run in a loopback-only network namespace (unshare -n)"
    if not (shutil.which("unshare") and shutil.which("ip")):
        return "unshare and ip (util-linux, iproute2) are needed for a loopback-only network namespace"
    return None


def run_checks(module: str, *, timeout: float, own_pids: bool = False) -> str:
    """Runs pytest on `tests/ray_cluster/<module>` in the namespace; fails with the output's tail unless every check
    passed; returns pytest's summary line. Skips the calling test when `why_not()` says so."""
    reason = why_not()
    if reason:
        pytest.skip(reason)
    path = REPO / "tests" / "ray_cluster" / module
    checks = f"{shlex.join(PYTEST)} -q -p no:cacheprovider -x -o python_files={module} {shlex.quote(str(path))}"
    # `; exit $?`: bash stays the namespace's first process (it reaps what `ray start` leaves to it)
    inner = f"ip link set lo up && {checks}; exit $?"
    flags = ["-n", "-p", "--kill-child", "--mount-proc"] if own_pids else ["-n"]
    with tempfile.TemporaryDirectory() as scratch:
        # Not in the repository: the checks' working folder goes on their Ray workers' sys.path (Ray does
        # that), where they would import the tree beside the installed package.
        done = subprocess.run(
            ["unshare", *flags, "bash", "-c", inner],
            cwd=scratch,
            capture_output=True,
            text=True,
            timeout=timeout,
            env={**os.environ, **RAY_TEST_ENV},
        )
    # A failure's report from its start (what failed, then the logs it carries), else the output's tail.
    failures = done.stdout.partition("= FAILURES =")[2]
    summary = (failures[:20000] if failures else "\n".join(done.stdout.splitlines()[-40:])) + "\n" + done.stderr[-3000:]
    assert done.returncode == 0, summary
    last = done.stdout.splitlines()[-1]
    assert " passed" in done.stdout and "skipped" not in last, summary
    return last
