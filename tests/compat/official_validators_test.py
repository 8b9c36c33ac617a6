"""`compat.submission_specs` refuses exactly what the official validators refuse (waymo-open-dataset 1.6.7
checks a scenario_id, 32 joint scenes, 80 or 91 positions and headings per object, and that the objects are
the sim agents): anything else a program sends is accepted, as the official accepts it."""

from __future__ import annotations

import math

import pytest

from wosac_eval import challenges
from wosac_eval.compat import submission_specs
from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.sim import scenes
from wosac_eval.sim.scene_recipes import SCENE_KINDS

SCENARIO = scenes.generate_scene(0, SCENE_KINDS.index("intersection"))
SG = submission_specs.ChallengeType.SCENARIO_GEN
SA = submission_specs.ChallengeType.SIM_AGENTS


def zero_scene(challenge, **extra) -> sim_agents_submission_pb2.JointScene:
    """Zero positions for every sim agent, as the official tests build them (no sizes, no type)."""
    steps = challenges.spec(challenge).num_simulation_steps
    scene = sim_agents_submission_pb2.JointScene()
    for object_id in challenges.sim_agent_ids(SCENARIO).tolist():
        trajectory = scene.simulated_trajectories.add(object_id=object_id)
        for name in ("center_x", "center_y", "center_z", "heading"):
            getattr(trajectory, name).extend([0.0] * steps)
        for name, values in extra.items():
            getattr(trajectory, name).extend(values)
    return scene


@pytest.mark.parametrize("challenge", [SA, SG])
def test_the_official_tests_zero_scene_is_valid(challenge):
    submission_specs.validate_joint_scene(zero_scene(challenge), SCENARIO, challenge)
    rollouts = sim_agents_submission_pb2.ScenarioRollouts(
        scenario_id=SCENARIO.scenario_id, joint_scenes=[zero_scene(challenge)] * 32
    )
    submission_specs.validate_scenario_rollouts(rollouts, SCENARIO, challenge)


def test_what_the_official_lets_through_is_accepted():
    nan = zero_scene(SA)
    nan.simulated_trajectories[0].center_x[3] = math.nan
    submission_specs.validate_joint_scene(nan, SCENARIO, SA)
    repeated = zero_scene(SA)
    repeated.simulated_trajectories.append(repeated.simulated_trajectories[0])
    submission_specs.validate_joint_scene(repeated, SCENARIO, SA)
    odd_boxes = zero_scene(SG, length=[0.0] * 80)  # a wrong number of box sizes: not checked officially
    submission_specs.validate_joint_scene(odd_boxes, SCENARIO, SG)


def test_what_the_official_refuses_is_refused():
    short = zero_scene(SA)
    del short.simulated_trajectories[0].heading[-1]
    with pytest.raises(ValueError, match="heading"):
        submission_specs.validate_joint_scene(short, SCENARIO, SA)
    missing = zero_scene(SA)
    del missing.simulated_trajectories[0]
    with pytest.raises(ValueError, match="missing"):
        submission_specs.validate_joint_scene(missing, SCENARIO, SA)
    extra = zero_scene(SA)
    stranger = extra.simulated_trajectories.add(object_id=10**9)
    for name in ("center_x", "center_y", "center_z", "heading"):
        getattr(stranger, name).extend([0.0] * 80)
    with pytest.raises(ValueError):
        submission_specs.validate_joint_scene(extra, SCENARIO, SA)
    with pytest.raises(ValueError, match="80"):
        submission_specs.validate_joint_scene(zero_scene(SG), SCENARIO, SA)  # 91 steps for sim agents
    too_few = sim_agents_submission_pb2.ScenarioRollouts(
        scenario_id=SCENARIO.scenario_id, joint_scenes=[zero_scene(SA)] * 31
    )
    with pytest.raises(ValueError):
        submission_specs.validate_scenario_rollouts(too_few, SCENARIO, SA)
    with pytest.raises(ValueError, match="scenario_id"):
        submission_specs.validate_scenario_rollouts(sim_agents_submission_pb2.ScenarioRollouts(), SCENARIO, SA)
