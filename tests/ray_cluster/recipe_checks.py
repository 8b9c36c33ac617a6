"""The Ray cluster recipe of docs/ray.md, run as written with real `ray start` processes (Ray 2.60, token auth).

Run by `ray_start_recipe_test.py` inside network and PID namespaces of their own
(`loopback.run_checks(own_pids=True)`): only loopback, so the head listens on the
recipe's own port 6379 and no traffic leaves 127.0.0.1; its own processes, so
`ray stop` (which stops every Ray process it can see) stops only these, and the
last check can see that every process the recipe started is gone. HOME and
RAY_TMPDIR are fresh folders: a user's ~/.ray/auth_token and /tmp/ray session
are never read or touched. Not collected on its own (its name matches no test pattern).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from support.paths import REPO
from support.processes import alive
from wosac_eval.scoring.submission import score_submission
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import make_submission

BIN = Path(sys.executable).parent
HEAD_PORT = 6379  # the recipe's (docs/ray.md); free in a fresh network namespace
ADDRESS = f"127.0.0.1:{HEAD_PORT}"
CLIENT_ADDRESS = "ray://127.0.0.1:10001"  # the head's Ray Client server: what the service's compose file uses
# The recipe of docs/ray.md; `--num-cpus=1` only keeps two nodes light on a small machine.
HEAD = ["ray", "start", "--head", f"--port={HEAD_PORT}", "--num-cpus=1"]
NODE = ["ray", "start", f"--address={ADDRESS}", "--num-cpus=1"]
STOP = ["ray", "stop"]
NO_TOKEN_LINE = "requires token authentication and this process sent no token: set RAY_AUTH_MODE=token"

if os.getppid() != 1:  # not the first process's child: not in a PID namespace of our own
    pytest.skip(
        "run by ray_start_recipe_test.py in a PID namespace of its own: `ray stop` here would stop "
        "every Ray process of the machine",
        allow_module_level=True,
    )


def canonical(result) -> str:
    return json.dumps(result, sort_keys=True)


def live_pids() -> set[int]:
    return {int(entry) for entry in os.listdir("/proc") if entry.isdigit() and alive(int(entry))}


def describe(pids) -> str:
    out = []
    for pid in sorted(pids):
        try:
            command = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            command = "(gone)"
        out.append(f"{pid}: {command[:200]}")
    return "\n".join(out)


@pytest.fixture(scope="module")
def env():
    """A fresh HOME and RAY_TMPDIR (short: Ray's socket paths live under it), and no Ray settings of the caller."""
    root = Path(tempfile.mkdtemp(prefix="wr", dir="/tmp"))
    (root / "home").mkdir()
    (root / "tmp").mkdir()
    base = {k: v for k, v in os.environ.items() if not k.startswith(("RAY_ADDRESS", "RAY_AUTH"))}
    base.update(
        HOME=str(root / "home"),
        RAY_TMPDIR=str(root / "tmp"),
        RAY_DISABLE_USAGE_STATS="1",
        PATH=os.pathsep.join([str(BIN), os.environ.get("PATH", "")]),
    )
    yield base
    shutil.rmtree(root, ignore_errors=True)


def run(command: list[str], env: dict, timeout: float = 300, **extra) -> subprocess.CompletedProcess:
    # In the run's fresh HOME, not the repository: a Ray driver's working folder goes on its workers' sys.path,
    # and there they would import the tree beside the installed package.
    return subprocess.run(
        command, env={**env, **extra}, cwd=env["HOME"], capture_output=True, text=True, timeout=timeout
    )


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Two synthetic scenes in one shard, a constant-velocity submission, and the local engine's result."""
    root = tmp_path_factory.mktemp("recipe")
    shards = scenes.write_scenario_shards(scenes.generate_scenes(2, seed=4), root / "scenarios", num_shards=1)
    submission = make_submission(shards, "constant_velocity", root / "cv.tar.gz")
    return {
        "scenarios": [str(p) for p in shards],
        "submission": str(submission),
        "local": score_submission(shards, submission),
        "out": root,
    }


@pytest.fixture(scope="module")
def cluster(env):
    """The recipe's cluster: a token (generated once), RAY_AUTH_MODE=token, a head and a second node."""
    before = live_pids()
    token_env = {**env, "RAY_AUTH_MODE": "token"}
    generated = run(["ray", "get-auth-token", "--generate"], env)
    assert generated.returncode == 0, generated.stderr
    token = (Path(env["HOME"]) / ".ray" / "auth_token").read_text()
    assert token == generated.stdout and len(token) >= 32
    try:
        # As users run it: the head's Ray Client server keeps its default 30 s wait for the server process
        # it starts per client. A longer wait (300 s, tried) turns that process's failed start into a
        # 300 s hang: Ray's log-stream proxy waits as long for the failed process's channel, and the
        # client's clean-up of the failed connection waits for the log stream; with 30 s the failure
        # reaches `ray_executor.connect` in about 40 s, which starts the connection again.
        for command in (HEAD, NODE):
            done = run(command, token_env)
            assert done.returncode == 0, f"{' '.join(command)}:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
        yield {"before": before, "token_env": token_env, "token": token}
    finally:
        if live_pids() - before:  # a check failed before the last one stopped the cluster
            run(STOP + ["--force"], token_env)


def test_the_documentation_gives_this_recipe():
    section = (REPO / "docs" / "ray.md").read_text()
    for text in (
        "ray get-auth-token --generate",
        "export RAY_AUTH_MODE=token",
        "ray start --head --port=6379",
        "ray start --address=HEAD_IP:6379",
        "--engine ray --ray-address HEAD_IP:6379",
        "ray stop",
    ):
        assert text in section, text


def test_both_nodes_joined(cluster):
    """`ray status` shows the autoscaler's view, refreshed every few seconds: wait for the second node there."""
    deadline, done = time.monotonic() + 180, None
    while time.monotonic() < deadline:
        done = run(["ray", "status", f"--address={ADDRESS}"], cluster["token_env"], timeout=120)
        assert done.returncode == 0, done.stdout + done.stderr
        if done.stdout.split("Active:", 1)[-1].split("Pending:", 1)[0].count("node_") == 2:
            return
        time.sleep(1)
    raise AssertionError(f"the second node is not active after 180 s:\n{done.stdout}")


def test_the_cluster_scores_exactly_as_the_local_engine(cluster, data):
    out = data["out"] / "ray.json"
    done = run(
        [
            "wosac-eval",
            "score",
            "--scenarios",
            *data["scenarios"],
            "--submission",
            data["submission"],
            "--engine",
            "ray",
            "--ray-address",
            ADDRESS,
            "-o",
            str(out),
        ],
        cluster["token_env"],
    )
    assert done.returncode == 0, done.stderr[-5000:]
    assert canonical(json.loads(out.read_text())) == canonical(data["local"])


def error_lines(done: subprocess.CompletedProcess) -> list[str]:
    assert done.returncode == 2, done.stdout[-2000:] + done.stderr[-5000:]
    return done.stderr.strip().splitlines()


@contextlib.contextmanager
def service(root: Path, data: dict, env: dict, address: str, **extra: str):
    """The scoring service fanning its jobs out to `address`, in `env` (+ `extra`); yields a client and a
    function that submits the test's submission and waits for its job to end (done or failed)."""
    from support.server_harness import Server

    server = Server(root, [Path(p) for p in data["scenarios"]], RAY_ADDRESS=address)
    for key in [k for k in server.env if k.startswith(("RAY_AUTH", "RAY_ADDRESS"))]:
        del server.env[key]
    server.env.update({k: v for k, v in env.items() if not k.startswith("WOSAC_")}, **extra)
    server.start(timeout=120)

    def wait(client, submitted):
        try:
            return server.wait_state(client, submitted, timeout=300)
        except AssertionError as stuck:  # say what the cluster's side was doing (a CI run once saw this)
            raise AssertionError(f"{stuck}\n{ray_logs(env)}") from None

    try:
        with server.client(server.key("team")) as client:
            submitted = client.post("/v1/submissions", content=Path(data["submission"]).read_bytes()).json()["id"]
            yield client, lambda: wait(client, submitted)
    finally:
        server.stop()


def ray_logs(env: dict, lines: int = 30) -> str:
    """The tails of the head's Ray Client server logs (the per-client servers' too, named when empty: a
    server process that died before writing a line) and of every error log of this cluster's session."""
    logs = Path(env["RAY_TMPDIR"]) / "ray" / "session_latest" / "logs"
    out = []
    for path in dict.fromkeys(sorted(logs.glob("ray_client_server*")) + sorted(logs.glob("*.err"))):
        text = path.read_text(errors="replace").strip().splitlines()[-lines:]
        if text or path.name.startswith("ray_client_server"):
            out.append(f"--- {path.name}\n" + ("\n".join(text) or "(empty)"))
    return "\n".join(out) or f"(no Ray logs under {logs})"


def test_a_client_without_the_right_token_gets_one_line_that_names_the_fix(cluster, env, data, tmp_path):
    """The reported case (no RAY_AUTH_MODE: Ray sends no token to an explicit address, although the token
    is right there in this HOME), a wrong token, RAY_AUTH_MODE=token with no token at all (another HOME),
    and a Ray Client (ray://) without RAY_AUTH_MODE: one line each, naming what to set; and the service
    without RAY_AUTH_MODE fails its job with the first case's line, at its first attempt. All but the third
    wait out Ray's retries (20 s; the Ray Client's 30 s), side by side."""

    def score(address):
        return [
            "wosac-eval",
            "score",
            "--scenarios",
            *data["scenarios"],
            "--submission",
            data["submission"],
            "--engine",
            "ray",
            "--ray-address",
            address,
            "-o",
            str(data["out"] / "never.json"),
        ]

    empty_home = data["out"] / "empty-home"
    empty_home.mkdir()
    cases = {
        "no mode": (ADDRESS, {}),
        "wrong token": (ADDRESS, {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": "0" * 64}),
        "no token": (ADDRESS, {"RAY_AUTH_MODE": "token", "HOME": str(empty_home)}),
        "client, no mode": (CLIENT_ADDRESS, {}),
    }
    with service(tmp_path / "service", data, env, ADDRESS) as (_, job):
        procs = {
            name: subprocess.Popen(
                score(address),
                env={**env, **extra},
                cwd=env["HOME"],  # not the repository (see `run`)
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            for name, (address, extra) in cases.items()
        }
        done = {}
        for name, proc in procs.items():
            stdout, stderr = proc.communicate(timeout=300)
            done[name] = subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)
        status = job()
    lines = {name: error_lines(d) for name, d in done.items()}
    assert all(len(v) == 1 for v in lines.values()), lines
    assert f"the Ray cluster at {ADDRESS} {NO_TOKEN_LINE}" in lines["no mode"][0], lines
    assert "rejected the authentication token from RAY_AUTH_TOKEN" in lines["wrong token"][0], lines
    assert "RAY_AUTH_MODE=token found no token" in lines["no token"][0], lines
    assert f"cannot connect to the Ray cluster at {CLIENT_ADDRESS}" in lines["client, no mode"][0], lines
    assert "set RAY_AUTH_MODE=token" in lines["client, no mode"][0], lines
    assert all("ray get-auth-token" in v[0] and "RAY_AUTH_TOKEN_PATH" in v[0] for v in lines.values()), lines
    assert status["state"] == "failed", status
    assert f"the Ray cluster at {ADDRESS} {NO_TOKEN_LINE}" in status["error"] and "\n" not in status["error"], status
    assert "attempts" not in status["error"], status  # a refused token is not tried again: it would be the same


def test_the_service_with_the_token_scores_through_a_ray_client(cluster, env, data, tmp_path):
    """As the service's compose file runs it (WOSAC_RAY_ADDRESS=ray://head:10001), with RAY_AUTH_MODE=token."""
    with service(tmp_path / "service", data, env, CLIENT_ADDRESS, RAY_AUTH_MODE="token") as (client, job):
        status = job()
        assert status["state"] == "done", status.get("error")
        assert canonical(client.get(f"/v1/submissions/{status['id']}/results").json()) == canonical(data["local"])


def test_ray_stop_leaves_no_process_behind(cluster):
    done = run(STOP, cluster["token_env"], timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    deadline, left = time.monotonic() + 120, None
    while time.monotonic() < deadline:
        left = live_pids() - cluster["before"]
        if not left:
            break
        time.sleep(0.2)
    assert not left, f"still running after `ray stop`:\n{describe(left)}"
