"""Scoring through the service, end to end: golden submissions give exactly what
`score_submission` gives; a worker killed with SIGKILL mid-job is replaced and
the job completes; a job past its time budget fails with the reason; a restart
keeps finished results. Real scorer, real worker processes, real SQLite file."""
from __future__ import annotations

import csv
import io
import json
import os
import signal
import time

import pytest

from .conftest import GOLDEN_PAIR, SCENARIO_FILES, canonical, need_scorer, need_shared, tar_bytes

RUNNING = ("validating", "scoring")


@pytest.fixture(scope="module")
def golden_pair_archive(tmp_path_factory) -> bytes:
    """A valid two-shard .tar.gz covering both shared scenarios: the golden submissions
    for each, the second one's metadata made equal to the first's (shards must agree)."""
    need_shared()
    need_scorer()
    from wosac_eval.protos import sim_agents_submission_pb2 as pb

    first, second = (pb.SimAgentsChallengeSubmission.FromString(p.read_bytes()) for p in GOLDEN_PAIR)
    merged = pb.SimAgentsChallengeSubmission()
    merged.CopyFrom(first)
    del merged.scenario_rollouts[:]
    merged.scenario_rollouts.extend(second.scenario_rollouts)
    return tar_bytes({"shard-00000-of-00002.binproto": first.SerializeToString(),
                      "shard-00001-of-00002.binproto": merged.SerializeToString()})


@pytest.fixture(scope="module")
def direct_pair_result(golden_pair_archive, tmp_path_factory) -> dict:
    """`score_submission` called directly on the same archive the tests upload."""
    from wosac_eval.metrics.submission import score_submission

    path = tmp_path_factory.mktemp("direct") / "pair.tar.gz"
    path.write_bytes(golden_pair_archive)
    return json.loads(canonical(score_submission(SCENARIO_FILES, path, "2025")))


def test_golden_submissions_score_exactly_as_score_submission(make_server, golden_pair_archive,
                                                              direct_pair_result, direct_single_result):
    server = make_server(workers=1)
    key = server.key("golden")
    with server.client(key) as c:
        pair_id = c.post("/v1/submissions", content=golden_pair_archive,
                         params={"publish": "true", "method": "log-replay+const-vel"}).json()["id"]
        single_id = c.post("/v1/submissions", content=GOLDEN_PAIR[0].read_bytes(),
                           params={"allow_partial": "true"}).json()["id"]
        pair = server.wait_state(c, pair_id)
        assert pair["state"] == "done", pair
        assert pair["progress"] == {"scenarios_done": 2, "scenarios_total": 2}
        assert pair["attempts"] == 1 and pair["error"] is None
        served = c.get(f"/v1/submissions/{pair_id}/results")
        assert served.headers["content-type"] == "application/json"
        assert canonical(served.json()) == canonical(direct_pair_result)
        assert pair["realism_meta_metric"] == direct_pair_result["buckets"]["realism_meta_metric"]

        rows = list(csv.DictReader(io.StringIO(c.get(f"/v1/submissions/{pair_id}/results",
                                                     params={"format": "csv"}).text)))
        assert [r["scenario_id"] for r in rows] == [s["scenario_id"] for s in direct_pair_result["scenarios"]]
        for row, scen in zip(rows, direct_pair_result["scenarios"]):
            assert float(row["metametric"]) == scen["metametric"]

        board = c.get("/v1/leaderboard", params={"config": "2025"}).json()
        assert [e["method"] for e in board["entries"]] == ["log-replay+const-vel"]
        assert board["entries"][0]["realism_meta_metric"] == direct_pair_result["buckets"]["realism_meta_metric"]
        assert board["entries"][0]["buckets"] == direct_pair_result["buckets"]

        one = server.wait_state(c, single_id)
        assert one["state"] == "done", one
        assert canonical(c.get(f"/v1/submissions/{single_id}/results").json()) == canonical(direct_single_result)
        assert c.get("/v1/leaderboard").json()["entries"][0]["method"] == "log-replay+const-vel"  # unpublished


def test_invalid_submission_fails_with_its_report(make_server):
    need_scorer()
    need_shared()
    server = make_server(workers=1)
    with server.client(server.key("invalid")) as c:
        # A well-formed archive whose shard is not a submission proto.
        sid = c.post("/v1/submissions", content=tar_bytes({"shard.binproto": b"\xff" * 64})).json()["id"]
        status = server.wait_state(c, sid)
    assert status["state"] == "failed"
    assert status["error"].startswith("the submission is invalid")
    assert status["validation_report"]["text"]


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


def test_job_of_a_killed_worker_completes_and_survives_restart(make_server, direct_single_result):
    server = make_server(workers=1)
    key = server.key("killer")
    body, partial = GOLDEN_PAIR[0].read_bytes(), {"allow_partial": "true"}
    with server.client(key) as c:
        sid = c.post("/v1/submissions", content=body, params=partial).json()["id"]
        victim = _running_worker_pid(server, sid)
        os.kill(victim, signal.SIGKILL)
        status = server.wait_state(c, sid)
        assert status["state"] == "done", status
        assert status["attempts"] == 2  # the killed attempt, then the one that finished
        assert canonical(c.get(f"/v1/submissions/{sid}/results").json()) == canonical(direct_single_result)
        # Accepted while the server is going down: must be scored after the restart.
        queued_id = c.post("/v1/submissions", content=body, params=partial).json()["id"]
    server.stop()
    again = make_server(data_dir=server.data_dir, workers=1)
    with again.client(key) as c:
        assert canonical(c.get(f"/v1/submissions/{sid}/results").json()) == canonical(direct_single_result)
        assert again.wait_state(c, queued_id)["state"] == "done"
        assert canonical(c.get(f"/v1/submissions/{queued_id}/results").json()) == canonical(direct_single_result)


def test_job_over_its_time_budget_fails_with_the_reason(make_server):
    need_shared()
    need_scorer()
    server = make_server(workers=1, job_time_budget_s=0.3, heartbeat_s=0.05)
    with server.client(server.key("slow")) as c:
        sid = c.post("/v1/submissions", content=GOLDEN_PAIR[0].read_bytes(),
                     params={"allow_partial": "true"}).json()["id"]
        status = server.wait_state(c, sid, timeout=30)
    assert status["state"] == "failed"
    assert "exceeded its time budget of 0.3 s" in status["error"]
    assert status["attempts"] == 1
