"""`--backend jax` end to end: CLI and library give the numpy results; a clear error without JAX."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from support.paths import REPO, require_shared
from support.runs import run_score

CASE = "637f20cafde22ff8__official_test_submission"


@pytest.mark.ci  # XLA compiling for real golden scenes in the CLI's processes: about a minute on 2 cores
@pytest.mark.parametrize("workers", [1, 2])
def test_cli_jax_backend_matches_golden_and_numpy(tmp_path, workers):
    shared = require_shared()
    args = [
        "--scenarios",
        str(shared / "womd" / "motion_data_one_scenario.tfrecord"),
        "--submission",
        str(shared / "golden" / f"{CASE}.binproto"),
        "--workers",
        str(workers),
    ]
    proc, result = run_score(tmp_path, *args, "--backend", "jax")
    assert proc.returncode == 0, proc.stderr
    golden = json.loads((shared / "golden" / f"{CASE}.json").read_text())["metrics"]["2025"]
    for field, value in result["aggregate"].items():
        assert value == pytest.approx(golden[field], abs=1e-5), field
    for field, value in result["buckets"].items():
        assert value == pytest.approx(golden["buckets"][field], abs=1e-5), field
    (tmp_path / "jax.json").write_text(json.dumps(result))
    proc, numpy_result = run_score(tmp_path, *args)
    assert proc.returncode == 0, proc.stderr
    # Bit-identical features give identical metrics.
    assert result["scenarios"] == numpy_result["scenarios"]
    assert result["aggregate"] == numpy_result["aggregate"]


@pytest.mark.slow  # XLA compiling for real golden scenes: about a minute on 2 cores
def test_score_submission_jax_batches_several_scenarios(tmp_path):
    shared = require_shared()
    from wosac_eval.scoring.submission import score_submission
    from wosac_eval.protos import sim_agents_submission_pb2

    # One submission with both real scenarios, scored in one batched jax pass.
    cases = [CASE, "ee519cf571686d19__constvel_noise"]
    parts = [
        sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(
            (shared / "golden" / f"{case}.binproto").read_bytes()
        )
        for case in cases
    ]
    combined = parts[0]
    combined.scenario_rollouts.extend(parts[1].scenario_rollouts)
    submission = tmp_path / "both.binproto"
    submission.write_bytes(combined.SerializeToString())
    jax_result = score_submission(shared / "womd", submission, backend="jax")
    numpy_result = score_submission(shared / "womd", submission)
    assert jax_result["num_scenarios"] == 2
    assert jax_result["scenarios"] == numpy_result["scenarios"]
    assert jax_result["aggregate"] == numpy_result["aggregate"]
    for case, scored in zip(cases, jax_result["scenarios"]):
        golden = json.loads((shared / "golden" / f"{case}.json").read_text())["metrics"]["2025"]
        from wosac_eval.metrics.scenario_metrics import SCENARIO_FIELDS

        for field in SCENARIO_FIELDS:
            assert scored[field] == pytest.approx(golden[field], abs=1e-5), (case, field)


def test_missing_jax_is_a_usage_error_with_the_install_hint(tmp_path):
    shared = require_shared()
    # A real interpreter in which `import jax` fails, as in an install without the extra.
    code = "import sys; sys.modules['jax'] = None; from wosac_eval.fronts.cli import main; sys.exit(main(sys.argv[1:]))"
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            code,
            "score",
            "--scenarios",
            str(shared / "womd"),
            "--submission",
            str(shared / "golden" / f"{CASE}.binproto"),
            "--backend",
            "jax",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2
    assert "pip install 'wosac-eval[jax]'" in proc.stderr


def test_unknown_backend_is_rejected():
    from wosac_eval.extras import check_backend

    with pytest.raises(ValueError, match="unknown backend 'torch'"):
        check_backend("torch")


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_pipelined_jax_file_path_equals_numpy_on_demo_scenes(tmp_path):
    """Workers prepare on the host, this process feeds the device: the whole document equals numpy's. (The
    scenes of tests/analysis/criticality_cache_test.py's JAX run: the same programs, compiled once.)"""
    from wosac_eval.scoring.submission import score_submission
    from wosac_eval.sim import scenes
    from wosac_eval.sim.baselines import make_submission

    shards = scenes.write_scenario_shards(scenes.generate_scenes(5, seed=0), tmp_path / "scenarios", num_shards=2)
    submission = make_submission(shards, "idm", tmp_path / "idm.tar.gz", num_shards=2)
    numpy_result = score_submission(shards, submission)
    for workers in (1, 2):
        assert score_submission(shards, submission, backend="jax", workers=workers) == numpy_result
