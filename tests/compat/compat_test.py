"""`wosac_eval.compat`: code written for the official modules runs by changing its imports.

The official tutorial's code path (load a config, validate each scenario's
rollouts, compute its `SimAgentMetrics`, aggregate, bucket), run on official
submissions, gives the official outputs; `scenario_to_joint_scene` gives the
official converter's bytes.
"""

from __future__ import annotations

import numpy as np
import pytest

from support import golden
from support.paths import TEST_DATA

# The official imports, changed as a user would change them.
from wosac_eval.compat import converters, metrics, submission_specs
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2

COMPAT_DATA = TEST_DATA / "oracle_compat"
CHALLENGE_TYPES = {
    "sim_agents": submission_specs.ChallengeType.SIM_AGENTS,
    "scenario_gen": submission_specs.ChallengeType.SCENARIO_GEN,
}


def tutorial_metrics(scenario: scenario_pb2.Scenario, rollouts, challenge_type, config):
    """The tutorial's per-scenario steps, verbatim but for the imports."""
    submission_specs.validate_scenario_rollouts(rollouts, scenario, challenge_type)
    return metrics.compute_scenario_metrics_for_bundle(config, scenario, rollouts, challenge_type=challenge_type)


@pytest.mark.parametrize(("case_set", "case"), golden.all_cases())
def test_tutorial_code_path_gives_the_official_metrics(case_set, case):
    golden.skip_if_absent(case_set, case)
    rollouts = golden.rollouts(case_set, case)
    scenario = golden.scenario(rollouts.scenario_id)
    challenge_type = CHALLENGE_TYPES[case_set.challenge]
    config = metrics.load_metrics_config(challenge_type)  # the challenge's current config
    config_name = "2025" if case_set.challenge == "sim_agents" else "scenario_gen_2025"
    expected = golden.expected_metrics(case_set, case, config_name)
    scenario_metrics = tutorial_metrics(scenario, rollouts, challenge_type, config)
    assert scenario_metrics.DESCRIPTOR.name == "SimAgentMetrics"
    assert scenario_metrics.scenario_id == rollouts.scenario_id
    for field, value in expected.items():
        if field != "buckets":
            assert getattr(scenario_metrics, field) == pytest.approx(value, abs=1e-5), field
    aggregate = metrics.aggregate_scenario_metrics([scenario_metrics])
    buckets = metrics.aggregate_metrics_to_buckets(config, aggregate)
    for field, value in expected["buckets"].items():
        assert getattr(buckets, field) == pytest.approx(value, abs=1e-5), field


def test_aggregation_is_the_mean_of_each_field():
    from wosac_eval.protos import sim_agents_metrics_pb2 as pb

    first = pb.SimAgentMetrics(scenario_id="a", metametric=0.5, linear_speed_likelihood=0.25)
    second = pb.SimAgentMetrics(scenario_id="b", metametric=0.7, linear_speed_likelihood=0.75)
    mean = metrics.aggregate_scenario_metrics([first, second])
    assert mean.metametric == pytest.approx(0.6) and mean.linear_speed_likelihood == pytest.approx(0.5)
    assert not mean.HasField("scenario_id")
    with pytest.raises(ValueError, match="no scenario metrics"):
        metrics.aggregate_scenario_metrics([])


@pytest.mark.parametrize(
    "scene", ["oracle/scenes/occlusion.tfrecord", "oracle_scenario_gen/scenes/synthetic-5-008-pedestrians.tfrecord"]
)
@pytest.mark.parametrize("challenge", ["sim_agents", "scenario_gen"])
def test_scenario_to_joint_scene_is_the_official_converter(scene, challenge):
    from wosac_eval.parse.scenarios import iter_scenarios

    scenario = next(s for s, _ in iter_scenarios(TEST_DATA / scene))
    official = (COMPAT_DATA / f"{scenario.scenario_id}__{challenge}.joint_scene.binproto").read_bytes()
    ours = converters.scenario_to_joint_scene(scenario, CHALLENGE_TYPES[challenge])
    assert ours.SerializeToString() == official


def test_submission_specs_match_the_official_values():
    for challenge_type, steps in (
        (submission_specs.ChallengeType.SIM_AGENTS, 80),
        (submission_specs.ChallengeType.SCENARIO_GEN, 91),
    ):
        config = submission_specs.get_submission_config(challenge_type)
        assert (
            config.current_time_index,
            config.n_simulation_steps,
            config.n_rollouts,
            config.step_duration_seconds,
        ) == (10, steps, 32, 0.1)
    assert submission_specs.ChallengeType("scenario_gen") is submission_specs.ChallengeType.SCENARIO_GEN


def _occlusion_scene() -> scenario_pb2.Scenario:
    from wosac_eval.parse.scenarios import iter_scenarios

    return next(s for s, _ in iter_scenarios(TEST_DATA / "oracle" / "scenes" / "occlusion.tfrecord"))


def test_sim_agent_and_evaluation_ids():
    scenario = _occlusion_scene()
    sim_agents = submission_specs.get_sim_agent_ids(scenario, submission_specs.ChallengeType.SIM_AGENTS)
    assert sim_agents == [t.id for t in scenario.tracks if t.states[10].valid]
    evaluated = submission_specs.get_evaluation_sim_agent_ids(scenario, submission_specs.ChallengeType.SIM_AGENTS)
    wanted = {scenario.tracks[scenario.sdc_track_index].id} | {
        scenario.tracks[r.track_index].id for r in scenario.tracks_to_predict
    }
    assert evaluated == sorted(wanted)
    assert (
        submission_specs.get_evaluation_sim_agent_ids(scenario, submission_specs.ChallengeType.SCENARIO_GEN)
        == sim_agents
    )


def test_validators_raise_value_error_naming_the_fault():
    scenario = _occlusion_scene()
    scene = converters.scenario_to_joint_scene(scenario)
    submission_specs.validate_joint_scene(scene, scenario, submission_specs.ChallengeType.SIM_AGENTS)
    short = sim_agents_submission_pb2.JointScene()
    short.CopyFrom(scene)
    del short.simulated_trajectories[0].center_x[-1]
    with pytest.raises(ValueError, match="center_x has 79 values, expected 80"):
        submission_specs.validate_joint_scene(short, scenario, submission_specs.ChallengeType.SIM_AGENTS)
    missing = sim_agents_submission_pb2.JointScene()
    missing.CopyFrom(scene)
    gone = missing.simulated_trajectories[3].object_id
    del missing.simulated_trajectories[3]
    with pytest.raises(ValueError, match=f"{gone}"):
        submission_specs.validate_joint_scene(missing, scenario, submission_specs.ChallengeType.SIM_AGENTS)
    rollouts = sim_agents_submission_pb2.ScenarioRollouts(scenario_id=scenario.scenario_id, joint_scenes=[scene] * 31)
    with pytest.raises(ValueError, match="found 31 joint scenes, expected 32"):
        submission_specs.validate_scenario_rollouts(rollouts, scenario)
    with pytest.raises(ValueError, match="scenario_id"):
        submission_specs.validate_scenario_rollouts(sim_agents_submission_pb2.ScenarioRollouts(), scenario)
    # A sim agents joint scene is no scenario gen joint scene: 80 steps, and the hint says so.
    with pytest.raises(ValueError, match="80 values"):
        submission_specs.validate_joint_scene(scene, scenario, submission_specs.ChallengeType.SCENARIO_GEN)


def test_tutorial_simulation_from_arrays():
    """The tutorial builds its submission from a simulator's states, one joint scene per rollout."""
    from wosac_eval.arrays.messages import joint_scene

    scenario = _occlusion_scene()
    ids = submission_specs.get_sim_agent_ids(scenario, submission_specs.ChallengeType.SIM_AGENTS)
    tracks = {t.id: t for t in scenario.tracks}
    current = np.array(
        [
            [
                tracks[i].states[10].center_x,
                tracks[i].states[10].center_y,
                tracks[i].states[10].center_z,
                tracks[i].states[10].heading,
                tracks[i].states[10].velocity_x,
                tracks[i].states[10].velocity_y,
            ]
            for i in ids
        ]
    )
    rng = np.random.default_rng(0)
    scenes = []
    for _ in range(32):  # constant velocity with noisy speed, as the tutorial's extrapolation
        t = np.arange(1, 81) * 0.1 * rng.uniform(0.8, 1.2)
        x = current[:, 0:1] + current[:, 4:5] * t
        y = current[:, 1:2] + current[:, 5:6] * t
        scenes.append(joint_scene(ids, x, y, np.repeat(current[:, 2:3], 80, 1), np.repeat(current[:, 3:4], 80, 1)))
    for scene in scenes:
        submission_specs.validate_joint_scene(scene, scenario, submission_specs.ChallengeType.SIM_AGENTS)
    rollouts = sim_agents_submission_pb2.ScenarioRollouts(joint_scenes=scenes, scenario_id=scenario.scenario_id)
    config = metrics.load_metrics_config(submission_specs.ChallengeType.SIM_AGENTS)
    result = tutorial_metrics(scenario, rollouts, submission_specs.ChallengeType.SIM_AGENTS, config)
    from wosac_eval import score_scenario

    assert result.metametric == pytest.approx(score_scenario(scenario, rollouts)["metametric"], abs=0)
    assert 0 < result.metametric < 1
