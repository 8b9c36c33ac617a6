"""Programs written for the official waymo-open-dataset package, run on wosac-eval with no line changed after the
one-line opt-in: an evaluator and per-step realism logger (`programs/official_evaluator.py`), and an evaluation
pool whose spawn and forkserver workers import the official modules (`programs/official_pool_evaluator.py`).
Each runs as a separate program outside the repository (the installed package), as a user's does; its numbers
are checked against the library's own pipeline, called independently."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest

from support.paths import REPO, TEST_DATA, require_shared
from wosac_eval import read_scenarios, score_scenario
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.compat import converters, official_finder
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.config import preset_path
from wosac_eval.protos import sim_agents_submission_pb2

PROGRAMS = REPO / "tests" / "compat" / "programs"


def run_program(name: str, *args: str, cwd) -> dict:
    env = {k: v for k, v in os.environ.items() if k != official_finder.ENVIRONMENT}
    done = subprocess.run(
        [sys.executable, str(PROGRAMS / name), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    result = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    assert result, done.stdout[-2000:]
    return json.loads(result[-1][len("RESULT ") :])


def scene(source: str):
    if source == "womd":
        return next(iter(read_scenarios(require_shared("womd") / "womd" / "motion_data_one_scenario.tfrecord")))
    return next(iter(read_scenarios(TEST_DATA / "oracle" / "scenes" / "collision.tfrecord")))


@pytest.mark.slow  # a fresh interpreter scoring 32 rollouts: 6-7 s
@pytest.mark.parametrize("source", ["repository", "womd"])
def test_the_official_evaluator_runs_with_its_imports_unchanged(source, tmp_path):
    scenario = scene(source)
    (tmp_path / "scenario.binproto").write_bytes(scenario.SerializeToString())
    result = run_program("official_evaluator.py", "scenario.binproto", "out", cwd=tmp_path)
    # The config it joined to waymo_open_dataset.__path__[0] is the one preset file, the metrics the library's.
    assert os.path.samefile(result["config_path"], preset_path("2025"))
    assert result["metrics_module"] == "wosac_eval.compat.metrics"
    rollouts = sim_agents_submission_pb2.ScenarioRollouts.FromString(
        (tmp_path / "out" / "rollouts.binproto").read_bytes()
    )
    assert np.float32(result["metametric"]) == np.float32(score_scenario(scenario, rollouts)["metametric"])
    # Its realism log of rollout 0 holds the library's per-step features of that rollout, object by object.
    logged = np.load(tmp_path / "out" / "features.npz")
    _, sim = scenario_features(scenario_arrays(scenario), rollout_arrays(rollouts))
    rows = [list(logged["object_id"]).index(i) for i in sim.object_id]
    reported = slice(11, None)
    pairs = {
        "linear_speed": "linear_speed",
        "angular_acceleration": "angular_acceleration",
        "distance_to_nearest_object": "distance_to_nearest_object",
        "time_to_collision": "time_to_collision",
        "distance_to_road_edge": "distance_to_road_edge",
        "red_light_violation": "traffic_light_violation_per_step",
    }
    for ours, theirs in pairs.items():
        got, expected = logged[ours][rows][:, reported], np.asarray(sim.feature(theirs)[0])
        if ours in ("linear_speed", "angular_acceleration", "red_light_violation"):
            np.testing.assert_array_equal(got, expected, err_msg=ours)
        else:  # the program's object order rounds a few sines of the official packet otherwise: the last bit
            np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5, err_msg=ours)
            assert (got == expected).mean() > 0.99, ours
    assert result["collision_rate"] == pytest.approx(float(logged["collision"][:, reported].mean()))


@pytest.mark.slow  # two pools of fresh interpreters
@pytest.mark.parametrize("method", ["spawn", "forkserver"])
def test_an_evaluation_pool_serves_the_official_names_in_its_workers(method, tmp_path):
    hook = Path(sysconfig.get_path("purelib")) / "wosac_eval_official_names.pth"
    assert hook.is_file(), f"{hook} is missing: an installation older than the hook; reinstall (pip install -e .)"
    scenario = scene("repository")
    logged = converters.scenario_to_joint_scene(scenario)
    rollouts = sim_agents_submission_pb2.ScenarioRollouts(scenario_id=scenario.scenario_id, joint_scenes=[logged] * 32)
    (tmp_path / "scenario.binproto").write_bytes(scenario.SerializeToString())
    (tmp_path / "rollouts.binproto").write_bytes(rollouts.SerializeToString())
    scored = run_program(
        "official_pool_evaluator.py", method, *["scenario.binproto:rollouts.binproto"] * 3, cwd=tmp_path
    )
    expected = np.float32(score_scenario(scenario, rollouts)["metametric"])
    assert [np.float32(s["metametric"]) for s in scored] == [expected] * 3
    assert {s["metrics_module"] for s in scored} == {"wosac_eval.compat.metrics"}
    assert os.getpid() not in {s["pid"] for s in scored}
