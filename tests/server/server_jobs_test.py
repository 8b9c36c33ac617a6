"""Scoring through the service, end to end: the golden submissions of ../shared (or
demo data when it is absent) give exactly what `score_submission` gives; a worker
killed with SIGKILL mid-job is replaced and the job completes; a job past its time
budget fails with the reason; a restart keeps finished results. Real scorer, real
worker processes, real SQLite file."""

from __future__ import annotations

import csv
import io
import json
import os
import signal
import time

import pytest

from support.processes import alive, processes_of
from support.server_harness import as_submission, canonical, tar_bytes

# The service end to end (jobs through real workers: killed, restarted, retried): the CI tier's (`pytest --ci`).
pytestmark = pytest.mark.ci

RUNNING = ("validating", "scoring")


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_submissions_score_exactly_as_score_submission(
    make_server, scoring_data, direct_full_result, direct_single_result
):
    server = make_server(workers=1, scenarios=scoring_data.scenarios)
    n = len(scoring_data.scenarios)
    with server.client(server.key("golden")) as c:
        full_id = c.post(
            "/v1/submissions",
            content=scoring_data.full.read_bytes(),
            params={"publish": "true", "method": "baseline-1"},
        ).json()["id"]
        single_id = c.post(
            "/v1/submissions", content=scoring_data.single.read_bytes(), params={"allow_partial": "true"}
        ).json()["id"]
        full = server.wait_state(c, full_id)
        assert full["state"] == "done", full
        assert full["progress"] == {"scenarios_done": n, "scenarios_total": n}
        assert full["attempts"] == 1 and full["error"] is None
        served = c.get(f"/v1/submissions/{full_id}/results")
        assert served.headers["content-type"] == "application/json"
        assert canonical(served.json()) == canonical(direct_full_result)
        assert full["realism_meta_metric"] == direct_full_result["buckets"]["realism_meta_metric"]

        rows = list(
            csv.DictReader(io.StringIO(c.get(f"/v1/submissions/{full_id}/results", params={"format": "csv"}).text))
        )
        assert [r["scenario_id"] for r in rows] == [s["scenario_id"] for s in direct_full_result["scenarios"]]
        for row, scen in zip(rows, direct_full_result["scenarios"]):
            assert float(row["metametric"]) == scen["metametric"]

        board = c.get("/v1/leaderboard", params={"config": "2025"}).json()
        assert [e["method"] for e in board["entries"]] == ["baseline-1"]
        assert board["entries"][0]["realism_meta_metric"] == direct_full_result["buckets"]["realism_meta_metric"]
        assert board["entries"][0]["buckets"] == direct_full_result["buckets"]

        one = server.wait_state(c, single_id)
        assert one["state"] == "done", one
        assert canonical(c.get(f"/v1/submissions/{single_id}/results").json()) == canonical(direct_single_result)
        assert [e["method"] for e in c.get("/v1/leaderboard").json()["entries"]] == ["baseline-1"]  # unpublished


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_invalid_submission_fails_with_its_report(make_server, scoring_data):
    server = make_server(workers=1, scenarios=scoring_data.scenarios)
    with server.client(server.key("invalid")) as c:
        # A well-formed archive whose shard is not a submission proto.
        sid = c.post("/v1/submissions", content=tar_bytes({"shard.binproto": as_submission(b"\xff" * 64)})).json()["id"]
        status = server.wait_state(c, sid)
        assert c.get(f"/v1/submissions/{sid}/results").status_code == 409
    assert status["state"] == "failed"
    assert status["error"].startswith("the submission is invalid: ") and "error(s)" in status["error"]
    assert "invalid submission" not in status["error"]  # said once, not twice
    assert "shard.binproto" in status["validation_report"]["text"]
    assert status["validation_report"]["details"]["valid"] is False
    # No absolute server path in what a client sees: the upload is called `submission`.
    shown = json.dumps(status)
    for secret in {str(server.data_dir), str(server.data_dir.resolve()), *map(str, scoring_data.scenarios)}:
        assert secret not in shown, secret
    assert "submission" in status["validation_report"]["text"]


def _running_worker_pid(server, submission_id: str, timeout: float = 60.0) -> int:
    """The pid of the worker holding the job's lease, read from the job store."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        row = server.store.fetchone("SELECT state, lease_owner FROM submissions WHERE id = ?", (submission_id,))
        if row["state"] in RUNNING and row["lease_owner"]:
            return int(row["lease_owner"].split(":")[1])
        assert row["state"] == "queued", f"job reached {row['state']} before it could be killed"
        time.sleep(0.01)
    raise AssertionError("no worker claimed the job")


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_job_of_a_killed_worker_completes_and_survives_restart(make_server, scoring_data, direct_single_result):
    server = make_server(workers=1, scenarios=scoring_data.scenarios)
    key = server.key("killer")
    body, partial = scoring_data.single.read_bytes(), {"allow_partial": "true"}
    with server.client(key) as c:
        sid = c.post("/v1/submissions", content=body, params=partial).json()["id"]
        victim = _running_worker_pid(server, sid)
        os.kill(victim, signal.SIGKILL)
        status = server.wait_state(c, sid)
        assert status["state"] == "done", status
        assert status["attempts"] == 2  # the killed attempt, then the one that finished
        assert _lease_owner_pid(server, sid) is None
        assert canonical(c.get(f"/v1/submissions/{sid}/results").json()) == canonical(direct_single_result)
        # Accepted while the server is going down: must be scored after the restart.
        queued_id = c.post("/v1/submissions", content=body, params=partial).json()["id"]
    server.stop()
    again = make_server(data_dir=server.data_dir, workers=1, scenarios=scoring_data.scenarios)
    with again.client(key) as c:
        assert canonical(c.get(f"/v1/submissions/{sid}/results").json()) == canonical(direct_single_result)
        assert again.wait_state(c, queued_id)["state"] == "done"
        assert canonical(c.get(f"/v1/submissions/{queued_id}/results").json()) == canonical(direct_single_result)


def _lease_owner_pid(server, sid):
    return server.store.fetchone("SELECT lease_owner FROM submissions WHERE id = ?", (sid,))["lease_owner"]


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_job_over_its_time_budget_fails_with_the_reason(make_server, scoring_data):
    server = make_server(workers=1, scenarios=scoring_data.scenarios, job_time_budget_s=0.05, heartbeat_s=0.02)
    with server.client(server.key("slow")) as c:
        sid = c.post("/v1/submissions", content=scoring_data.full.read_bytes()).json()["id"]
        status = server.wait_state(c, sid, timeout=30)
    assert status["state"] == "failed"
    assert "exceeded its time budget of 0.05 s" in status["error"]
    assert status["attempts"] == 1


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_server_killed_mid_job_leaves_no_orphan_and_the_job_completes_after_restart(
    make_server, scoring_data, direct_single_result
):
    server = make_server(workers=1, scenarios=scoring_data.scenarios)
    key = server.key("crash")
    with server.client(key) as c:
        sid = c.post(
            "/v1/submissions", content=scoring_data.single.read_bytes(), params={"allow_partial": "true"}
        ).json()["id"]
    worker = _running_worker_pid(server, sid)
    server.proc.kill()  # SIGKILL: no shutdown code runs in the server process
    server.proc.wait()
    deadline = time.monotonic() + 20
    while alive(worker) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(worker), "the worker outlived its server"
    again = make_server(data_dir=server.data_dir, workers=1, scenarios=scoring_data.scenarios)
    with again.client(key) as c:
        status = again.wait_state(c, sid)
        assert status["state"] == "done", status
        assert status["attempts"] == 1  # the orphaned worker gave the job back: no attempt lost
        assert canonical(c.get(f"/v1/submissions/{sid}/results").json()) == canonical(direct_single_result)


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_scenario_gen_jobs_have_their_own_leaderboard(make_server, tmp_path):
    """A scenario-gen submission is validated and scored as such, lands on the scenario-gen
    leaderboard (not the sim agents one), and a partial result shows its coverage."""
    from wosac_eval.scoring.submission import score_submission
    from wosac_eval.sim import scenes
    from wosac_eval.sim.baselines import make_submission

    shards = scenes.write_scenario_shards(scenes.generate_scenes(2, seed=6), tmp_path / "scenarios", num_shards=2)
    full = make_submission(shards, "constant_velocity", tmp_path / "sg.tar.gz", challenge="scenario_gen")
    half = make_submission(shards[:1], "log_replay_noise", tmp_path / "sg-half.tar.gz", challenge="scenario_gen")
    direct = score_submission(shards, full, challenge="scenario_gen")
    server = make_server(workers=1, scenarios=shards)
    with server.client(server.key("generator")) as c:
        refused = c.post(
            "/v1/submissions", content=full.read_bytes(), params={"challenge": "scenario_gen", "config": "2025"}
        )
        assert refused.status_code == 422 and "scenario_gen_2025" in refused.json()["detail"]
        as_sim_agents = c.post("/v1/submissions", content=full.read_bytes()).json()
        ids = [
            c.post(
                "/v1/submissions",
                content=path.read_bytes(),
                params={
                    "challenge": "scenario_gen",
                    "publish": "true",
                    "method": method,
                    "allow_partial": str(method == "half").lower(),
                },
            ).json()["id"]
            for path, method in ((full, "whole"), (half, "half"))
        ]
        statuses = [server.wait_state(c, i) for i in ids]
        assert [s["state"] for s in statuses] == ["done", "done"], statuses
        assert statuses[0]["challenge"] == "scenario_gen" and statuses[0]["config"] == "scenario_gen_2025"
        assert statuses[0]["coverage"] == 1.0 and statuses[1]["coverage"] == 0.5
        assert canonical(c.get(f"/v1/submissions/{ids[0]}/results").json()) == canonical(direct)
        wrong = server.wait_state(c, as_sim_agents["id"])
        assert wrong["state"] == "failed" and "--challenge scenario_gen" in wrong["validation_report"]["text"]
        board = c.get("/v1/leaderboard", params={"challenge": "scenario_gen"}).json()
        assert board["challenge"] == "scenario_gen" and board["config"] == "scenario_gen_2025"
        assert {e["method"]: e["coverage"] for e in board["entries"]} == {"whole": 1.0, "half": 0.5}
        assert c.get("/v1/leaderboard").json()["entries"] == []  # the sim agents board
        page = c.get("/").text
        assert 'id="leaderboard-scenario_gen"' in page and "whole" in page and 'class="partial"' in page


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_metadata_gaps_fail_a_job_unless_the_service_is_set_to_warn(make_server, tmp_path):
    """The service keeps the challenge server's metadata rules by default; WOSAC_METADATA_CHECKS=warn
    scores such a submission and its result lists the gaps as warnings."""
    from wosac_eval.arrays.submission_writer import SubmissionMetadata
    from wosac_eval.sim import scenes
    from wosac_eval.sim.baselines import make_submission

    shards = scenes.write_scenario_shards(scenes.generate_scenes(1, seed=8), tmp_path / "scenarios", num_shards=1)
    anonymous = SubmissionMetadata(unique_method_name="anon", account_name="", authors=[])
    upload = make_submission(
        shards, "constant_velocity", tmp_path / "anon.tar.gz", num_shards=1, metadata=anonymous
    ).read_bytes()
    for checks, state in (("error", "failed"), ("warn", "done")):
        server = make_server(workers=1, scenarios=shards, data_dir=tmp_path / f"data-{checks}", metadata_checks=checks)
        with server.client(server.key(checks)) as c:
            status = server.wait_state(c, c.post("/v1/submissions", content=upload).json()["id"])
            assert status["state"] == state, status
            if state == "failed":
                assert "account_name is empty" in status["validation_report"]["text"]
            else:
                findings = c.get(f"/v1/submissions/{status['id']}/results").json()["validation"]["findings"]
                assert {(f["code"], f["severity"]) for f in findings} >= {("metadata.missing", "warning")}
        server.stop()


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_killed_job_process_leaves_no_scoring_process_behind(make_server, scoring_data):
    """A job's process scoring with a pool (WOSAC_SCORE_THREADS=2) killed as the OOM killer would: the
    pool's processes end with it (they would otherwise wait on their queue forever, each holding its
    memory), the job fails with the reason, and after the server stops none of its processes is left."""
    server = make_server(workers=1, scenarios=scoring_data.scenarios, score_threads=2)
    idle = set(processes_of(server.data_dir))  # the API (which supervises the workers) and its worker
    with server.client(server.key("pool")) as c:
        sid = c.post("/v1/submissions", content=scoring_data.full.read_bytes()).json()["id"]
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # until the job's process has its pool running
            parents = list(processes_of(server.data_dir).values())
            job_process = next((pid for pid in set(parents) - idle if parents.count(pid) >= 2), None)
            if job_process is not None:
                break
            assert c.get(f"/v1/submissions/{sid}").json()["state"] in ("queued", *RUNNING)
            time.sleep(0.005)
        assert job_process is not None, "the job's pool never started"
        os.kill(job_process, signal.SIGKILL)
        status = server.wait_state(c, sid)
        assert status["state"] == "failed" and "ended by SIGKILL" in status["error"], status
        deadline = time.monotonic() + 10
        while set(processes_of(server.data_dir)) - idle and time.monotonic() < deadline:
            time.sleep(0.1)
        assert set(processes_of(server.data_dir)) == idle
    server.stop()
    deadline = time.monotonic() + 10
    while processes_of(server.data_dir) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert processes_of(server.data_dir) == {}


@pytest.mark.slow  # over 4.5 s on 2 cores (the two waits): the full run's, not the fast tier's
def test_an_unreachable_scoring_engine_is_tried_again_before_the_job_fails(make_server, scoring_data):
    """WOSAC_RAY_ADDRESS names a Ray client port where nothing listens (a cluster down or restarting): the job
    connects again twice, 2 s then 4 s later, then fails with the reason and the number of attempts."""
    import socket

    pytest.importorskip("ray", reason="the ray engine needs the `ray` extra (without it a job fails at once)")

    with socket.socket() as probe:  # a loopback port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = make_server(workers=1, scenarios=scoring_data.scenarios, ray_address=f"ray://127.0.0.1:{port}")
    with server.client(server.key("engine")) as c:
        status = server.wait_state(c, c.post("/v1/submissions", content=scoring_data.full.read_bytes()).json()["id"])
    assert status["state"] == "failed", status
    assert status["error"].startswith("the scoring engine is unavailable: cannot reach the Ray cluster"), status
    assert status["error"].endswith("(3 attempts)"), status
    assert server.log.read_text().count("the scoring engine is unavailable") >= 2  # the two retries, logged


def test_a_job_without_the_ray_package_fails_at_once_with_the_install_hint(make_server, scoring_data):
    """Where Ray is not installed (the `test-core` environments), a job sent to a Ray cluster fails at its first
    try with the install command: no retry brings a package."""
    import importlib.util

    if importlib.util.find_spec("ray") is not None:
        pytest.skip("Ray is installed here: the unreachable-engine test covers the retries")
    server = make_server(workers=1, scenarios=scoring_data.scenarios, ray_address="ray://127.0.0.1:1")
    with server.client(server.key("no-ray")) as c:
        status = server.wait_state(c, c.post("/v1/submissions", content=scoring_data.full.read_bytes()).json()["id"])
    assert status["state"] == "failed", status
    assert "needs Ray, which is not installed" in status["error"] and "wosac-eval[ray]" in status["error"], status
    assert "attempts" not in status["error"]
    assert "trying again" not in server.log.read_text()
