import numpy as np
import pytest

from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.protos import sim_agents_submission_pb2 as sub_pb2


def _rollouts(values, ids, extra=None):
    scenes = []
    for r in range(values.shape[0]):
        trajectories = []
        for i, oid in enumerate(ids[r]):
            t = sub_pb2.SimulatedTrajectory(
                object_id=int(oid),
                center_x=values[r, i, 0].tolist(),
                center_y=values[r, i, 1].tolist(),
                center_z=values[r, i, 2].tolist(),
                heading=values[r, i, 3].tolist(),
            )
            if extra:
                extra(t)
            trajectories.append(t)
        scenes.append(sub_pb2.JointScene(simulated_trajectories=trajectories))
    return sub_pb2.ScenarioRollouts(scenario_id="s", joint_scenes=scenes)


def test_values_and_per_rollout_order_are_kept():
    rng = np.random.default_rng(0)
    values = rng.normal(0, 1000, size=(3, 4, 4, 80)).astype(np.float32)
    values[1, 2, 3, 7] = np.nan  # non-finite values are carried, validation rejects them earlier
    ids = np.array([[5, 1, 300, -2], [1, 5, 300, -2], [-2, 300, 5, 1]])
    arrays = rollout_arrays(_rollouts(values, ids))
    np.testing.assert_array_equal(arrays.object_id, ids)
    for k, field in enumerate(("x", "y", "z", "heading")):
        np.testing.assert_array_equal(getattr(arrays, field), values[:, :, k])
    assert arrays.x.dtype == np.float32 and arrays.num_rollouts == 3


def test_extra_fields_take_the_general_path_with_equal_results():
    rng = np.random.default_rng(1)
    values = rng.normal(size=(2, 3, 4, 80)).astype(np.float32)
    ids = np.array([[1, 2, 3], [1, 2, 3]])
    plain = rollout_arrays(_rollouts(values, ids))

    def with_sizes(t):
        t.length.extend([4.0] * 80)
        t.valid.extend([True] * 80)

    extended = rollout_arrays(_rollouts(values, ids, with_sizes))
    np.testing.assert_array_equal(plain.x, extended.x)
    np.testing.assert_array_equal(plain.heading, extended.heading)


def test_short_field_is_reported_with_scenario_rollout_and_field():
    values = np.zeros((2, 2, 4, 80), np.float32)
    rollouts = _rollouts(values, np.array([[1, 2], [1, 2]]))
    del rollouts.joint_scenes[1].simulated_trajectories[0].center_y[-1]
    with pytest.raises(ValueError, match=r"scenario s rollout 1: center_y"):
        rollout_arrays(rollouts)
