"""`waymo_open_dataset.utils.sim_agents.converters`, without TensorFlow.

`scenario_to_joint_scene`: the logged scene as a submission;
`joint_scene_to_trajectories` and `simulated_scenariogen_to_trajectories`:
a submitted joint scene as the `trajectory_utils.ObjectTrajectories` the
official features are computed from (numpy arrays, official dtypes).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.compat import submission_specs, trajectory_utils
from wosac_eval.compat._arrays import CompatArray, compat_array
from wosac_eval.compat.submission_specs import ChallengeType
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2


def scenario_to_joint_scene(
    scenario: scenario_pb2.Scenario, challenge_type: ChallengeType = ChallengeType.SIM_AGENTS
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
        raise ValueError(
            f"scenario {scenario.scenario_id}: the log has {log.num_steps} steps for the "
            f"{spec.challenge} challenge, which needs {spec.num_simulation_steps} (the test set has no "
            "future to copy)"
        )
    scene = sim_agents_submission_pb2.JointScene()
    for k, object_id in enumerate(log.object_id.tolist()):
        scene.simulated_trajectories.add(
            center_x=log.x[k].tolist(),
            center_y=log.y[k].tolist(),
            center_z=log.z[k].tolist(),
            heading=log.heading[k].tolist(),
            object_id=object_id,
            length=log.length[k].tolist(),
            width=log.width[k].tolist(),
            height=log.height[k].tolist(),
            object_type=int(log.object_type[k]),
            valid=log.valid[k].tolist(),
        )
    return scene


def _stacked(trajectories: Any, field: str, dtype: Any) -> np.ndarray:
    """One field of every submitted trajectory as `(num_objects, num_steps)` (`(num_objects,)` for scalars)."""
    values = [getattr(t, field) for t in trajectories]
    if values and not np.isscalar(values[0]):
        lengths = {len(v) for v in values}
        if len(lengths) > 1:
            raise ValueError(f"the joint scene's trajectories have {field} of different lengths ({sorted(lengths)})")
    return compat_array(values, dtype)


def joint_scene_to_trajectories(
    joint_scene: sim_agents_submission_pb2.JointScene, scenario: scenario_pb2.Scenario, use_log_validity: bool = False
) -> trajectory_utils.ObjectTrajectories:
    """A sim agents joint scene after the logged history: all 91 steps of its objects, in its order.

    Steps 0..10 come from the log; the submitted 80 steps follow. Box sizes
    are the log's at step 10 for every future step, object types the log's.
    The future is valid at every step, or, with `use_log_validity`, where
    the log is (as for the log's own features).

    Raises:
      ValueError: an object of the joint scene is not in the scenario.
    """
    log = trajectory_utils.ObjectTrajectories.from_scenario(scenario)
    now = submission_specs.get_submission_config(ChallengeType.SIM_AGENTS).current_time_index
    trajectories = joint_scene.simulated_trajectories
    ids = _stacked(trajectories, "object_id", np.int32)
    future = {
        name: _stacked(trajectories, field, np.float32)
        for name, field in (("x", "center_x"), ("y", "center_y"), ("z", "center_z"), ("heading", "heading"))
    }
    history = log.gather_objects_by_id(ids).slice_time(0, now + 1)
    n_future = future["x"].shape[-1] if future["x"].ndim == 2 else 0
    if use_log_validity:
        future_valid = log.gather_objects_by_id(ids).slice_time(now + 1).valid
    else:
        future_valid = np.ones((len(ids), n_future), dtype=bool)

    def frozen(a: np.ndarray) -> np.ndarray:
        return np.repeat(a[:, -1:], n_future, axis=-1)

    def joined(past: np.ndarray, rest: np.ndarray) -> CompatArray:
        return compat_array(np.concatenate([past, rest.reshape(len(ids), n_future)], axis=-1))

    return trajectory_utils.ObjectTrajectories(
        **{f: joined(getattr(history, f), future[f]) for f in ("x", "y", "z", "heading")},
        **{f: joined(getattr(history, f), frozen(getattr(history, f))) for f in ("length", "width", "height")},
        valid=joined(history.valid, future_valid),
        object_id=ids,
        object_type=history.object_type,
    )


def simulated_scenariogen_to_trajectories(
    joint_scene: sim_agents_submission_pb2.JointScene, scenario: scenario_pb2.Scenario, challenge_type: ChallengeType
) -> trajectory_utils.ObjectTrajectories:
    """A scenario gen joint scene as trajectories: the submitted positions, box sizes and types, in its order.

    The submitted validity is not used: each object is valid at every step
    where the log has it valid at the current step (step 10), as officially.

    Raises:
      ValueError: an object of the joint scene is not in the scenario.
    """
    trajectories = joint_scene.simulated_trajectories
    fields = {
        name: _stacked(trajectories, field, np.float32)
        for name, field in (
            ("x", "center_x"),
            ("y", "center_y"),
            ("z", "center_z"),
            ("heading", "heading"),
            ("length", "length"),
            ("width", "width"),
            ("height", "height"),
        )
    }
    ids = _stacked(trajectories, "object_id", np.int32)
    log = trajectory_utils.ObjectTrajectories.from_scenario(scenario).gather_objects_by_id(ids)
    now = submission_specs.get_submission_config(challenge_type).current_time_index
    n_steps = fields["x"].shape[-1] if fields["x"].ndim == 2 else 0
    valid = compat_array(np.repeat(log.valid[:, now, None], n_steps, axis=-1))
    return trajectory_utils.ObjectTrajectories(
        **fields, valid=valid, object_id=ids, object_type=_stacked(trajectories, "object_type", np.int32)
    )
