"""`wosac-eval score` end to end on real files: result JSON equals the official outputs, bit for bit."""

from __future__ import annotations

import json

import pytest

from support.paths import require_shared
from support.runs import run_score


@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_score_matches_golden(tmp_path, workers):
    shared = require_shared()
    case = "637f20cafde22ff8__official_test_submission"
    proc, result = run_score(
        tmp_path,
        "--scenarios",
        str(shared / "womd" / "motion_data_one_scenario.tfrecord"),
        "--submission",
        str(shared / "golden" / f"{case}.binproto"),
        "--workers",
        str(workers),
    )
    assert proc.returncode == 0, proc.stderr
    golden = json.loads((shared / "golden" / f"{case}.json").read_text())["metrics"]["2025"]
    assert result["config"] == "2025"
    assert [s["scenario_id"] for s in result["scenarios"]] == ["637f20cafde22ff8"]
    # One scenario: its aggregate and buckets are the official float32 values (JSON keeps them exactly).
    for field, value in result["aggregate"].items():
        assert value == golden[field], field
    for field, value in result["buckets"].items():
        assert value == golden["buckets"][field], field


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_score_refuses_incomplete_submission_and_partial_lists_skipped(tmp_path):
    shared = require_shared()
    args = [
        "--scenarios",
        str(shared / "womd"),
        "--submission",
        str(shared / "golden" / "637f20cafde22ff8__logreplay.binproto"),
    ]
    proc, result = run_score(tmp_path, *args)
    assert proc.returncode == 1
    assert "ee519cf571686d19" in proc.stderr and result is None
    proc, result = run_score(tmp_path, *args, "--partial")
    assert proc.returncode == 0, proc.stderr
    assert [s["scenario_id"] for s in result["skipped"]] == ["ee519cf571686d19"]
    assert "missing from the submission" in result["skipped"][0]["reason"]
    assert result["num_scenarios"] == 1


def test_score_usage_error_on_unknown_config(tmp_path):
    shared = require_shared()
    proc, _ = run_score(
        tmp_path,
        "--scenarios",
        str(shared / "womd"),
        "--submission",
        str(shared / "golden" / "637f20cafde22ff8__logreplay.binproto"),
        "--config",
        "2019",
    )
    assert proc.returncode == 2
    assert "2019" in proc.stderr


def test_unscorable_scenario_is_named(tmp_path):
    """A scenario the official code cannot score either (no road edges) gives a clear error."""
    shared = require_shared()
    from wosac_eval.scoring.scenario import score_scenario
    from wosac_eval.parse.scenarios import iter_scenarios
    from wosac_eval.protos import sim_agents_submission_pb2

    scenario = next(s for s, _ in iter_scenarios(shared / "womd" / "motion_data_one_scenario.tfrecord"))
    kept = [f for f in scenario.map_features if f.WhichOneof("feature_data") != "road_edge"]
    del scenario.map_features[:]
    scenario.map_features.extend(kept)
    raw = (shared / "golden" / "637f20cafde22ff8__logreplay.binproto").read_bytes()
    rollouts = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw).scenario_rollouts[0]
    with pytest.raises(ValueError, match="scenario 637f20cafde22ff8: cannot be scored: .*road edges"):
        score_scenario(scenario, rollouts)
