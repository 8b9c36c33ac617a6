"""The official Sim Agents tutorial, run end to end as a separate program with its imports changed.

`programs/tutorial_sim_agents.py` makes the tutorial's calls in the tutorial's
order (trajectories from the scenario, a noisy extrapolation policy, the map
and the animation, joint scenes, validation, one scene's features, the
scenario's metrics, a sharded submission in a tar.gz). Its outputs are
checked against the library's own pipeline, called independently.
"""

from __future__ import annotations

import glob
import json
import os
import subprocess
import sys
import tarfile

import numpy as np
import pytest

from support.paths import REPO, TEST_DATA, require_shared

PROGRAM = REPO / "tests" / "compat" / "programs" / "tutorial_sim_agents.py"


def _run(pattern: str, out) -> dict:
    env = dict(os.environ, MPLBACKEND="Agg")  # the program imports the installed package, as a user's does
    done = subprocess.run(
        [sys.executable, str(PROGRAM), pattern, str(out)], capture_output=True, text=True, env=env, timeout=600
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    assert "Simulation length, in steps: 80" in done.stdout
    assert "Number of parallel simulations per Scenario: 32" in done.stdout
    result = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    assert result, done.stdout[-2000:]
    return json.loads(result[-1][len("RESULT ") :])


# The repository's small scene in the full run; the real WOMD scene (16 s on 2 cores) in the CI tier.
@pytest.mark.slow  # among the longest outside Ray, browser and JAX (--durations): the full run's
@pytest.mark.parametrize("source", ["repository", pytest.param("womd", marks=pytest.mark.ci)])
def test_the_tutorial_runs_to_its_end_with_only_its_imports_changed(source, tmp_path):
    from wosac_eval import read_scenarios, score_scenario
    from wosac_eval.arrays.rollouts import rollout_arrays
    from wosac_eval.arrays.scenario import scenario_arrays
    from wosac_eval.compat import submission_specs
    from wosac_eval.features.metric_features import scenario_features
    from wosac_eval.protos import sim_agents_submission_pb2

    if source == "womd":
        pattern = str(require_shared("womd") / "womd" / "*.tfrecord")
    else:
        pattern = str(TEST_DATA / "oracle" / "scenes" / "[co]*.tfrecord")  # collision, occlusion, offroad
    out = tmp_path / "tutorial"
    result = _run(pattern, out)

    files = sorted(glob.glob(pattern))
    scenario = next(iter(read_scenarios(files[0])))
    assert result["scenario_id"] == scenario.scenario_id
    rollouts = sim_agents_submission_pb2.ScenarioRollouts.FromString(
        (out / "first_scenario_rollouts.binproto").read_bytes()
    )
    assert len(rollouts.joint_scenes) == 32
    # The metrics the program printed are the library's for the same rollouts (float32, exactly).
    assert np.float32(result["metametric"]) == np.float32(score_scenario(scenario, rollouts)["metametric"])
    # Its one scene's features are the library's features of rollout 0.
    _, sim = scenario_features(scenario_arrays(scenario), rollout_arrays(rollouts))
    features = np.load(out / "single_scene_features.npz")
    assert features["object_id"].dtype == np.int32
    np.testing.assert_array_equal(features["object_id"], sim.object_id)
    for name in (
        "valid",
        "linear_speed",
        "angular_acceleration",
        "distance_to_nearest_object",
        "time_to_collision",
        "distance_to_road_edge",
        "traffic_light_violation_per_step",
        "average_displacement_error",
    ):
        np.testing.assert_array_equal(features[name], getattr(sim, name)[:1], name)
    # The animation the notebook would show, and the submission archive: one shard per file, up to two
    # scenarios each, every one valid.
    page = (out / "animation.html").read_text()
    assert 'class="animation"' in page and page.count("data:image/png") == 80  # one frame per simulated step
    scenarios = {s.scenario_id: s for s in read_scenarios(files)}
    with tarfile.open(out / "submission.tar.gz") as tar:
        names = tar.getnames()
        assert names == result["shards"] and len(names) == len(files)
        for name in names:
            shard = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(tar.extractfile(name).read())
            assert shard.unique_method_name == "sim_agents_tutorial" and 1 <= len(shard.scenario_rollouts) <= 2
            for scenario_rollouts in shard.scenario_rollouts:
                submission_specs.validate_scenario_rollouts(scenario_rollouts, scenarios[scenario_rollouts.scenario_id])
