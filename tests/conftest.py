"""Fixtures for every test: the reference material in ../shared (or WOSAC_SHARED), when present.

The run fails when a process it started is still alive at its end (after every fixture's teardown
and a short grace period): each is reported by pid and command line, then killed. A run's processes
are its descendants, and every process carrying this run's `PYTEST_WOSAC_EVAL_SESSION` (set below,
inherited by every child) however it was re-parented: orphans adopted by pid 1 or a subreaper, and
daemons such as the PostgreSQL server of tests/server or the processes of a Ray cluster in its
`unshare -n` namespace. Under pytest-xdist each worker checks its own processes at its end and the
controller reports what the workers found.

Markers (registered in pyproject.toml) come from three places: the folder a test file lives in
(`FOLDER_MARKERS`), the fixtures a test uses (`FIXTURE_MARKERS`), and explicit marks in the test files
(browser, docker, slow). Ray, browser and Docker tests are also `slow`; Ray tests run one at a time
(`one_ray_cluster_at_a_time`).
"""

from __future__ import annotations

import fcntl
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from support.paths import JAX_TEST_CACHE, JAX_TEST_PROGRAMS, REPO, require_shared
from support.processes import alive, command_line, left_behind
from wosac_eval.runtime.cache_dirs import bounded

# Not a WOSAC_* name: the service harness passes no WOSAC_* variable of the test run on to a server.
SESSION_MARK = "PYTEST_WOSAC_EVAL_SESSION"
os.environ[SESSION_MARK] = uuid.uuid4().hex  # before any test starts a process: each inherits it
# The test process opts in to exact float32 on XLA's CPU (no fused multiply-adds), as a program does
# with `jax_backend.exact_cpu()`: here before anything can start JAX, and inherited by every child.
if "xla_cpu_max_isa" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_max_isa=AVX".strip()
# XLA's compiled programs kept on disk (JAX's persistent compilation cache), shared by the run's workers
# and every process they start, and by later runs: the JAX tests spend most of their time compiling, the
# same programs each run. A program is found by a digest of its HLO, the compiler's flags (XLA_FLAGS) and
# the JAX and XLA versions, so a changed program compiles anew. Set JAX_COMPILATION_CACHE_DIR to choose
# the folder (CI keeps its own between its runs, .ci/run). It is emptied at the start of a run when it
# holds more than 2 GiB (`runtime.cache_dirs.bounded`: not JAX's own size limit, which one interrupted write
# turns into a cache that stores nothing more).
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(JAX_TEST_CACHE))
if "PYTEST_XDIST_WORKER" not in os.environ:  # the run's first process, before any worker starts
    bounded(Path(os.environ["JAX_COMPILATION_CACHE_DIR"]), 2 << 30)
# The traced `--backend jax` programs likewise (`backends/program_cache`: found by a digest of the
# package's sources, so a changed kernel traces anew), never the user's own folder.
os.environ.setdefault("WOSAC_JAX_PROGRAM_CACHE", str(JAX_TEST_PROGRAMS))
LEAK_GRACE_S = 5.0
_LEAKS_KEY = pytest.StashKey[list]()
_NUMBA_WARM_UPS = pytest.StashKey[list]()
_LEAKS_OUTPUT = "wosac_processes_left_behind"  # in an xdist worker's workeroutput


def pytest_configure(config):
    """numba compiles the package's loops on their first call, once per installation (about 50 s of one
    core here), and caches them on disk beside the package. On a fresh installation (CI's, a newcomer's
    first run) every process that starts before one has written the cache compiles them too: both xdist
    workers, each process of a Ray cluster, the documents' commands (4 min more CPU in the README's test
    command). So an xdist run's controller compiles them first (`scoring.warm_up.compile_loops`; about 1 s when
    cached), while the workers start, and the tests wait for it (`pytest_runtestloop` below). For the
    installed package (`-I`: not this tree beside it), which every process of the tests imports: the
    test processes, the console scripts they run (`support.runs`) and the service harness's servers."""
    if "PYTEST_XDIST_WORKER" in os.environ or config.option.collectonly:
        return
    if not getattr(config.option, "numprocesses", None):
        return
    warm_up = "from wosac_eval.scoring.warm_up import compile_loops; compile_loops()"
    config.stash[_NUMBA_WARM_UPS] = [
        subprocess.Popen(
            [sys.executable, "-I", "-c", warm_up], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
    ]


@pytest.hookimpl(tryfirst=True)
def pytest_runtestloop(session):
    """Before the controller hands out the first test: the numba warm-up (above) has ended. One that
    failed (no installed copy) changes nothing: a test that calls the loops then compiles them."""
    for warm_up in session.config.stash.get(_NUMBA_WARM_UPS, []):
        warm_up.wait()


def pytest_unconfigure(config):
    for warm_up in config.stash.get(_NUMBA_WARM_UPS, []):  # a run that ended before its test loop
        warm_up.wait()


@pytest.fixture
def shared() -> Path:
    return require_shared()


@pytest.fixture(scope="session")
def run_root(request, tmp_path_factory) -> Path:
    """The folder of the whole test run, the same in every xdist worker: for what the workers share
    (locks, a set-up done once)."""
    root = tmp_path_factory.getbasetemp()
    if hasattr(request.config, "workerinput"):  # an xdist worker's basetemp is <the run's>/popen-gwN
        root = root.parent
    return root


@pytest.fixture(scope="session", autouse=True)
def criticality_cache_of_the_run(run_root):
    """Scenes' criticality kept (`analysis.criticality_cache`) in one file for the whole run, shared by its
    workers and every process they start (the service harness passes it on), never the user's own cache."""
    os.environ.setdefault("WOSAC_CRITICALITY_CACHE", str(run_root / "criticality.sqlite3"))


@pytest.fixture(autouse=True)
def one_ray_cluster_at_a_time(request, run_root):
    """The `ray` tests of one run take turns, whichever xdist worker runs them: two clusters at once are
    too heavy for 2 cores, and `ray stop` in the README's blocks would stop the other's. (A lock, not an
    xdist_group: pytest 9.2 drops the group from the node ids, pytest-xdist#1386.)"""
    if request.node.get_closest_marker("ray") is None:
        yield
        return
    with open(run_root / "ray-cluster.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        yield


@pytest.fixture(autouse=True)
def jax_programs_within_the_map_limit():
    """After a test, JAX's compiled programs are dropped once they hold half the process's memory-map
    limit (`jax_driver.drop_programs_near_map_limit`): an xdist worker that runs most JAX tests
    otherwise reaches `vm.max_map_count` and XLA segfaults in its next compile."""
    yield
    if "jax" in sys.modules:
        from wosac_eval.backends.jax_driver import drop_programs_near_map_limit

        drop_programs_near_map_limit()


# What a test needs, by the folder of tests/ its file lives in: a new file there gets the same marks.
FOLDER_MARKERS = {
    "backends": ("jax",),  # the JAX backend: JAX in the test process
    "parity": ("parity", "shared"),  # golden parity, on the reference material of ../shared
    "ray_cluster": ("ray",),  # a real Ray cluster in a loopback namespace
    "server": ("service",),  # the scoring service (wosac_server) as a real server
}
# ... and by the fixtures it uses.
FIXTURE_MARKERS = {"shared": ("shared",), "postgres_server": ("postgres",)}
# The CI tier: whole-system runs that CI makes once per run (`pytest --ci`), left out of a plain `pytest`
# (the README's command): Ray clusters, browsers, Docker, and what is explicitly marked `ci` (the documents'
# blocks, the full-scale paths compared, numerical gradient checks, the service end to end, the JAX backends
# over every golden case). Each is also `slow`: out of the fast tier (`pytest -m "not slow"`).
CI_MARKERS = ("ray", "browser", "docker", "ci")


def pytest_addoption(parser):
    parser.addoption(
        "--ci",
        action="store_true",
        help="also run the CI tier (marker `ci`: Ray clusters, browsers, Docker, the documents' blocks, "
        "the full-scale paths, the service end to end, the JAX backends over every golden case): a run "
        "that names no path and no -m leaves it out",
    )


def _markers(item) -> set[str]:
    tests = Path(__file__).parent
    folder = item.path.relative_to(tests).parts[0] if item.path.is_relative_to(tests) else ""
    names = set(FOLDER_MARKERS.get(folder, ()))
    for fixture, marks in FIXTURE_MARKERS.items():
        if fixture in item.fixturenames:
            names.update(marks)
    names.update(mark.name for mark in item.iter_markers())
    if names.intersection(CI_MARKERS):
        names.update(("ci", "slow"))
    return names


def pytest_itemcollected(item):
    """Marks each test by folder and fixtures (above), as it is collected: before `-m` selects."""
    names = _markers(item)
    for name in sorted(names - {mark.name for mark in item.iter_markers()}):
        item.add_marker(name)


def leaves_out_the_ci_tier(config) -> bool:
    """A plain run (the README's command: no path, no -m, no --ci) leaves the CI tier out; naming a file, a
    folder or a marker selects as pytest always does."""
    whole_run = config.args_source is pytest.Config.ArgsSource.TESTPATHS
    return whole_run and not config.option.markexpr and not config.getoption("--ci")


def pytest_collection_modifyitems(config, items):
    """The CI tier left out of a plain run (above); tests that start JAX run last: JAX runs threads, and
    later tests fork worker processes."""
    if leaves_out_the_ci_tier(config):
        left_out = [item for item in items if item.get_closest_marker("ci") is not None]
        if left_out:
            config.hook.pytest_deselected(items=left_out)
            items[:] = [item for item in items if item.get_closest_marker("ci") is None]
    items.sort(key=lambda item: item.get_closest_marker("jax") is not None)


def _multiprocessing_resource_tracker(pid: int, ppid: int) -> bool:
    """The standard library's resource tracker of this pytest process (started by the first spawned
    pool of a test run in-process): it has no public way to stop it and it ends when this process
    does (its pipe closes). The trackers of other processes are theirs: leaks if they outlive them."""
    return ppid == os.getpid() and "multiprocessing.resource_tracker" in command_line(pid)


@pytest.hookimpl(trylast=True)  # after the runner's own sessionfinish, which tears the last fixtures down
def pytest_sessionfinish(session, exitstatus):
    """Fail the run if a process it started outlives it: report each, then kill it. Under xdist each
    worker checks its own (they carry its mark) and sends them to the controller, which fails the run."""
    config = session.config
    if config.pluginmanager.hasplugin("dsession"):  # the xdist controller: it started only the workers
        leaks = config.stash.get(_LEAKS_KEY, [])
    elif sys.platform.startswith("linux"):
        leaks = _processes_left_behind()
        if hasattr(config, "workeroutput"):  # an xdist worker: sent to the controller when it ends
            config.workeroutput[_LEAKS_OUTPUT] = leaks
    else:
        return
    config.stash[_LEAKS_KEY] = leaks
    if leaks and session.exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


@pytest.hookimpl(optionalhook=True)  # an xdist hook: called on the controller as each worker ends
def pytest_testnodedown(node, error):
    leaks = getattr(node, "workeroutput", {}).get(_LEAKS_OUTPUT, [])
    worker = node.workerinput.get("workerid", "?")
    node.config.stash.setdefault(_LEAKS_KEY, []).extend(f"[{worker}] {line}" for line in leaks)


def _processes_left_behind() -> list[str]:
    """The processes of this test process still alive after a grace period, each as a line; kills them."""

    def ours() -> dict[int, int]:
        return {
            pid: ppid
            for pid, ppid in left_behind(os.getpid(), SESSION_MARK, os.environ[SESSION_MARK]).items()
            if not _multiprocessing_resource_tracker(pid, ppid)
        }

    deadline = time.monotonic() + LEAK_GRACE_S
    found = ours()
    while found and time.monotonic() < deadline:  # ending already (a worker that saw its server go)
        time.sleep(0.1)
        found = ours()
    if not found:
        return []
    leaks = [f"pid {pid} (parent {ppid}): {command_line(pid) or '?'}" for pid, ppid in sorted(found.items())]
    for pid in found:
        try:
            os.kill(pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
    time.sleep(0.5)
    still = [pid for pid in found if alive(pid)]
    if still:
        leaks.append(f"(still alive after SIGKILL: {still})")
    return leaks


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if leaves_out_the_ci_tier(config):  # (under xdist the workers collect: the controller names no count)
        terminalreporter.line(
            "the CI tier was left out (Ray clusters, browsers, Docker, the documents' blocks, the full-scale "
            "paths, the service end to end, the JAX backends over every golden case): `pytest -n auto --ci` "
            "runs it too, as CI does"
        )
    leaks = config.stash.get(_LEAKS_KEY, None)
    if not leaks:
        return
    terminalreporter.section("processes left behind", sep="!", red=True, bold=True)
    count = sum(" (parent " in line for line in leaks)
    terminalreporter.line(
        f"{count} process(es) started by this test run "
        f"were still alive {LEAK_GRACE_S:g} s after it ended (all fixtures torn down); "
        "killed them. The run fails:",
        red=True,
    )
    for line in leaks:
        terminalreporter.line("  " + line, red=True)
