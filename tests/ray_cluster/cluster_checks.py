"""The Ray engine on a real multi-node cluster (`ray.cluster_utils.Cluster`: a head and two nodes).

Run by `ray_engine_test.py` inside a network namespace with only loopback
(`unshare -n`), so no traffic leaves 127.0.0.1; not collected on its own (its
name matches no test pattern). Every check compares with the local engine:
the result document must be identical, value for value.

On a loaded machine everything here is slow, so the checks wait for conditions,
never for fixed times, and give them minutes (`NODES_TIMEOUT_S`...): a node killed
without warning stays alive in the GCS until its health checks fail (13 s on a
lightly loaded 2-core machine), where `Cluster.add_node` and `wait_for_nodes` wait
30 s at most, and a node's replacement registers in its own time.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
# Ray's worker processes import `ray_helpers` from here; they inherit the environment.
os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(HERE), os.environ.get("PYTHONPATH")]))
sys.path.insert(0, str(HERE))

import ray  # noqa: E402
from ray.cluster_utils import Cluster  # noqa: E402

import ray_helpers  # noqa: E402
from support.processes import alive  # noqa: E402
from support.runs import run_cli  # noqa: E402
from wosac_eval.extras import EngineUnavailableError  # noqa: E402
from wosac_eval.runtime.executors import make_executor  # noqa: E402
from wosac_eval.scoring import submission as scoring  # noqa: E402
from wosac_eval.scoring.submission import score_submission  # noqa: E402
from wosac_eval.sim import scenes  # noqa: E402
from wosac_eval.sim.baselines import make_submission  # noqa: E402
from wosac_eval.validate import validate_submission  # noqa: E402


NODES_TIMEOUT_S = 300  # nodes to register, and a killed node to be seen dead (Ray's default: 30 s)
JOB_TIMEOUT_S = 600  # one scoring job or run of tasks through the cluster


def canonical(result) -> str:
    return json.dumps(result, sort_keys=True)


def wait_for_exactly(c: Cluster, nodes: list) -> None:
    """Until the cluster's live nodes are exactly the head and `nodes`: every one registered (in its own
    time), and a killed one seen dead (it stays alive in the GCS until its health checks fail)."""
    expected = {c.head_node.node_id, *(node.node_id for node in nodes)}
    deadline, alive = time.monotonic() + NODES_TIMEOUT_S, set()
    while time.monotonic() < deadline:
        alive = {node["NodeID"] for node in ray.nodes() if node["Alive"]}
        if alive == expected:
            return
        time.sleep(0.2)
    raise AssertionError(f"after {NODES_TIMEOUT_S} s the live nodes are {sorted(alive)}, not {sorted(expected)}")


def replace_node(c: Cluster, nodes: list, k: int) -> None:
    """A fresh node in place of the one killed at `k`, once the cluster has exactly those."""
    nodes[k] = c.add_node(num_cpus=1, wait=False)
    wait_for_exactly(c, nodes)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Six synthetic scenes in two shards; submissions as a folder of shards (byte ranges) and as .tar.gz."""
    root = tmp_path_factory.mktemp("ray-data")
    shards = scenes.write_scenario_shards(scenes.generate_scenes(6, seed=2), root / "scenarios", num_shards=2)
    out = {"scenarios": [str(p) for p in shards]}
    out["sim_agents_folder"] = make_submission(shards, "constant_velocity", root / "cv", num_shards=3)
    out["scenario_gen_tar"] = make_submission(
        shards, "log_replay_noise", root / "sg.tar.gz", num_shards=2, challenge="scenario_gen"
    )
    return out


def test_cli_errors_at_once_when_the_cluster_is_unreachable(data):
    started = time.monotonic()
    done = run_cli(
        "score",
        "--scenarios",
        *data["scenarios"],
        "--submission",
        str(data["sim_agents_folder"]),
        "--engine",
        "ray",
        "--ray-address",
        "127.0.0.1:1",
        "-o",
        "/dev/null",
    )
    assert done.returncode == 2, done.stderr
    assert "cannot reach the Ray cluster at 127.0.0.1:1" in done.stderr
    assert time.monotonic() - started < 60
    with pytest.raises(EngineUnavailableError, match="not a Ray cluster address"):
        make_executor("ray", ray_address="127.0.0.1:port")


def test_cli_without_address_starts_a_local_ray(data, tmp_path):
    """Even where a dead cluster is still named in ray_current_cluster (Ray's own default would join it)."""
    local = score_submission(data["scenarios"], data["sim_agents_folder"])
    ray_tmp = Path(tempfile.mkdtemp(prefix="wr", dir="/tmp"))  # short: Ray's socket paths live under it
    (ray_tmp / "ray").mkdir()
    (ray_tmp / "ray" / "ray_current_cluster").write_text("127.0.0.1:1")
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"} | {"RAY_TMPDIR": str(ray_tmp)}
    done = run_cli(
        "score",
        "--scenarios",
        *data["scenarios"],
        "--submission",
        str(data["sim_agents_folder"]),
        "--engine",
        "ray",
        "-o",
        str(tmp_path / "r.json"),
        env=env,
        timeout=JOB_TIMEOUT_S,
    )
    shutil.rmtree(ray_tmp, ignore_errors=True)
    assert done.returncode == 0, done.stderr
    assert canonical(json.loads((tmp_path / "r.json").read_text())) == canonical(local)


@pytest.fixture(scope="module")
def cluster():
    # Ray's own settings of its node health checks, made quicker (Ray's defaults: a check every 3 s, a node
    # dead after 5 missed): a killed node is then found dead in about 1.5 s instead of 15.
    health = {"health_check_initial_delay_ms": 500, "health_check_period_ms": 500, "health_check_failure_threshold": 3}
    c = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "_system_config": health})
    nodes = [c.add_node(num_cpus=1, wait=False) for _ in range(2)]
    ray.init(address=c.address, log_to_driver=False)
    wait_for_exactly(c, nodes)
    yield c, nodes
    ray.shutdown()
    c.shutdown()


@pytest.mark.parametrize("kind, challenge", [("sim_agents_folder", "sim_agents"), ("scenario_gen_tar", "scenario_gen")])
def test_cluster_scores_exactly_as_local(cluster, data, kind, challenge):
    c, _ = cluster
    local = score_submission(data["scenarios"], data[kind], challenge=challenge)
    remote = score_submission(data["scenarios"], data[kind], challenge=challenge, engine="ray", ray_address=c.address)
    assert canonical(remote) == canonical(local)
    assert remote["num_scenarios"] == 6


def test_cluster_validation_report_equals_local(cluster, data, tmp_path):
    c, _ = cluster
    broken = tmp_path / "broken"
    broken.mkdir()
    for shard in sorted(Path(data["sim_agents_folder"]).iterdir()):
        (broken / shard.name).write_bytes(shard.read_bytes())
    (broken / "notes.bin").write_bytes(b"not a shard")
    last = sorted(broken.glob("*binproto*"))[-1]
    last.write_bytes(last.read_bytes()[:-100])  # a truncated shard
    local = validate_submission(data["scenarios"], broken)
    remote = validate_submission(data["scenarios"], broken, executor=make_executor("ray", ray_address=c.address))
    strip = lambda r: {k: v for k, v in r.to_dict(include_skipped=True).items() if k != "stats"}  # noqa: E731
    assert not local.ok and strip(remote) == strip(local)


def test_a_lost_driver_resumes_from_its_journal(cluster, data, tmp_path):
    """The driver's state is gone (its process died after 3 of 6 scenarios were journaled): the run
    again on the cluster scores only the other 3 and gives the uninterrupted result."""
    c, _ = cluster
    local = score_submission(data["scenarios"], data["sim_agents_folder"])
    journal = tmp_path / "run.journal"
    score_submission(data["scenarios"], data["sim_agents_folder"], engine="ray", ray_address=c.address, journal=journal)
    lines = journal.read_bytes().splitlines(keepends=True)
    journal.write_bytes(b"".join(lines[: 1 + 3]))  # the run's identity and the first 3 rows
    done: list[int] = []
    again = score_submission(
        data["scenarios"],
        data["sim_agents_folder"],
        engine="ray",
        ray_address=c.address,
        journal=journal,
        progress=lambda n, total: done.append(n),
    )
    assert canonical(again) == canonical(local)
    assert done[0] == 3 and done[-1] == 6


def test_a_killed_node_loses_no_work(cluster, data, monkeypatch):
    """A node removed without warning while its tasks run: they are retried elsewhere, same result."""
    c, nodes = cluster
    monkeypatch.setattr(scoring, "SCENARIOS_PER_TASK", 1)  # many small tasks: some run on the doomed node
    local = score_submission(data["scenarios"], data["scenario_gen_tar"], challenge="scenario_gen")
    first_result = threading.Event()
    out = {}

    def run():
        out["result"] = score_submission(
            data["scenarios"],
            data["scenario_gen_tar"],
            challenge="scenario_gen",
            engine="ray",
            ray_address=c.address,
            progress=lambda done, total: done and first_result.set(),
        )

    worker = threading.Thread(target=run)
    worker.start()
    assert first_result.wait(JOB_TIMEOUT_S), "scoring did not start"
    c.remove_node(nodes[1], allow_graceful=False)
    worker.join(JOB_TIMEOUT_S)
    assert not worker.is_alive(), f"scoring did not end in {JOB_TIMEOUT_S} s after the node was killed"
    assert canonical(out["result"]) == canonical(local)
    replace_node(c, nodes, 1)  # for the next checks


def test_tasks_of_a_dead_node_are_retried_elsewhere(cluster, tmp_path):
    """The mechanism itself: every item of a node that dies mid-task is started again and completed.

    Items hold until released (`ray_helpers.held_square`), and are released only once the worker
    process running the victim's item is gone: `remove_node` kills the node's raylet, its worker
    processes end when they notice (a second or so, longer under load), and one released before
    would finish its item there, so nothing would be retried (the old two-second item raced this)."""
    c, nodes = cluster
    log = tmp_path / "starts.log"
    release = Path(ray_helpers.release_path(str(log)))
    executor = make_executor("ray", ray_address=c.address)
    results = []
    thread = threading.Thread(target=lambda: results.extend(executor.imap(ray_helpers.held_square, range(9), str(log))))
    thread.start()
    by_id = {node.node_id: k for k, node in enumerate(nodes)}
    deadline, victim, worker = time.monotonic() + JOB_TIMEOUT_S, None, None
    try:
        while victim is None and time.monotonic() < deadline:  # the first worker node seen running an item
            starts = [line.split() for line in log.read_text().splitlines()] if log.exists() else []
            victim, worker = next(((by_id[node], int(pid)) for _, node, pid in starts if node in by_id), (None, None))
            time.sleep(0.05)
        assert victim is not None, f"no item ran on a worker node: {log.read_text() if log.exists() else ''}"
        c.remove_node(nodes[victim], allow_graceful=False)
        deadline = time.monotonic() + NODES_TIMEOUT_S
        while alive(worker) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not alive(worker), f"the killed node's worker process {worker} still runs after {NODES_TIMEOUT_S} s"
    finally:
        release.touch()  # whatever happened: no item waits on
    thread.join(JOB_TIMEOUT_S)
    assert not thread.is_alive(), f"the items did not end in {JOB_TIMEOUT_S} s:\n{log.read_text()}"
    assert results == [i * i for i in range(9)]
    starts = [int(line.split()[0]) for line in log.read_text().splitlines()]
    assert len(starts) > len(set(starts)), f"no item was started twice:\n{log.read_text()}"
    replace_node(c, nodes, victim)


def test_a_deterministic_failure_is_reported_not_retried(cluster, data, tmp_path):
    """A scenario that cannot be scored (no road edges) fails the run with its reason, at once."""
    c, _ = cluster
    scenario = scenes.generate_scenes(1, seed=9)[0]
    for feature in list(scenario.map_features):
        if feature.HasField("road_edge"):
            scenario.map_features.remove(feature)
    shards = scenes.write_scenario_shards([scenario], tmp_path / "scenarios", num_shards=1)
    submission = make_submission(shards, "constant_velocity", tmp_path / "cv.tar.gz")
    started = time.monotonic()
    with pytest.raises(ValueError, match=f"scenario {scenario.scenario_id}: cannot be scored.*road edges"):
        score_submission(shards, submission, engine="ray", ray_address=c.address)
    assert time.monotonic() - started < 120


def test_service_fans_jobs_out_to_the_cluster(cluster, data, tmp_path):
    from support.server_harness import Server

    c, _ = cluster
    local = score_submission(data["scenarios"], data["scenario_gen_tar"], challenge="scenario_gen")
    server = Server(
        tmp_path / "service", [Path(p) for p in data["scenarios"]], WOSAC_WORKERS=1, WOSAC_RAY_ADDRESS=c.address
    )
    server.start(timeout=120)  # under load the service's start alone can pass the harness's default 30 s
    try:
        with server.client(server.key("team")) as client:
            sid = client.post(
                "/v1/submissions",
                content=Path(data["scenario_gen_tar"]).read_bytes(),
                params={"challenge": "scenario_gen"},
            ).json()["id"]
            status = server.wait_state(client, sid, timeout=JOB_TIMEOUT_S)
            assert status["state"] == "done", status
            assert canonical(client.get(f"/v1/submissions/{sid}/results").json()) == canonical(local)
    finally:
        server.stop()
