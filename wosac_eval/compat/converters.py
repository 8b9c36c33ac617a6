"""`waymo_open_dataset.utils.sim_agents.converters`, without TensorFlow: the logged scene as a submission."""
from __future__ import annotations

from wosac_eval import challenges
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2

from wosac_eval.compat.submission_specs import ChallengeType


def scenario_to_joint_scene(scenario: scenario_pb2.Scenario,
                            challenge_type: ChallengeType = ChallengeType.SIM_AGENTS
                            ) -> sim_agents_submission_pb2.JointScene:
    """The logged trajectories of the sim agents as a `JointScene` (log replay; validation or training data only).

    Every field of each sim agent is copied from the log, whatever the validity
    of its states: the 80 future steps (sim agents) or all 91 (scenario gen),
    with box sizes, object type and validity, in track order.

    Raises:
      ValueError: the scenario does not have the challenge's number of steps (e.g. the test set, which has
        no future).
    """
    spec = challenges.spec(challenge_type)
    arrays = scenario_arrays(scenario)
    log = arrays.log.take_ids(arrays.sim_agent_ids)
    if spec.first_simulated_step:
        log = log.take_steps(slice(spec.first_simulated_step, None))
    if log.num_steps != spec.num_simulation_steps:
        raise ValueError(f"scenario {scenario.scenario_id}: the log has {log.num_steps} steps for the "
                         f"{spec.challenge} challenge, which needs {spec.num_simulation_steps} (the test set has no "
                         "future to copy)")
    scene = sim_agents_submission_pb2.JointScene()
    for k, object_id in enumerate(log.object_id.tolist()):
        scene.simulated_trajectories.add(
            center_x=log.x[k].tolist(), center_y=log.y[k].tolist(), center_z=log.z[k].tolist(),
            heading=log.heading[k].tolist(), object_id=object_id, length=log.length[k].tolist(),
            width=log.width[k].tolist(), height=log.height[k].tolist(), object_type=int(log.object_type[k]),
            valid=log.valid[k].tolist())
    return scene
