"""A simulator's arrays -> rollouts: checked, scored as they are, and serialised exactly as protobuf does."""

from __future__ import annotations

import numpy as np
import pytest

from wosac_eval import score_scenario
from wosac_eval.arrays.messages import (
    NonFiniteValueWarning,
    joint_scene,
    rollouts_bytes,
    rollouts_from_arrays,
    rollouts_message,
)
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.protos import sim_agents_submission_pb2 as pb
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import policy_rollouts


def protobuf_rollouts(scenario_id, ids, x, y, z, heading, sizes=None, types=None) -> pb.ScenarioRollouts:
    """The same rollouts built value by value with protobuf's own API."""
    message = pb.ScenarioRollouts(scenario_id=scenario_id)
    for r in range(x.shape[0]):
        scene = message.joint_scenes.add()
        for i, object_id in enumerate(ids):
            t = scene.simulated_trajectories.add(
                object_id=int(object_id),
                center_x=x[r, i].tolist(),
                center_y=y[r, i].tolist(),
                center_z=z[r, i].tolist(),
                heading=heading[r, i].tolist(),
            )
            if sizes is not None:
                t.length.extend(sizes[0][r, i].tolist())
                t.width.extend(sizes[1][r, i].tolist())
                t.height.extend(sizes[2][r, i].tolist())
                t.object_type = int(types[i])
    return message


def random_arrays(num_rollouts=3, num_objects=4, num_steps=80, seed=0):
    rng = np.random.default_rng(seed)
    coordinates = [rng.normal(0, 1e4, (num_rollouts, num_objects, num_steps)).astype(np.float32) for _ in range(4)]
    coordinates[0][0, 0, 0] = -0.0  # signed zero kept as is
    ids = np.array([7, -3, 2**31 - 1, 0])[:num_objects]  # a negative id takes a 10-byte varint
    return ids, coordinates


def test_bytes_are_protobufs_own_serialisation():
    ids, (x, y, z, h) = random_arrays()
    arrays = rollouts_from_arrays("scene-1", ids, x, y, z, h)
    assert rollouts_bytes(arrays) == protobuf_rollouts("scene-1", ids, x, y, z, h).SerializeToString()
    sizes = [np.full_like(x, value) for value in (4.5, 1.9, 1.6)]
    types = np.array([1, 2, 3, 1])
    boxed = rollouts_from_arrays(
        "scene-1", ids, x, y, z, h, length=sizes[0], width=sizes[1], height=sizes[2], object_type=types
    )
    assert rollouts_bytes(boxed) == protobuf_rollouts("scene-1", ids, x, y, z, h, sizes, types).SerializeToString()


def test_round_trip_through_the_reader():
    ids, (x, y, z, h) = random_arrays(num_steps=91)
    arrays = rollouts_from_arrays("s", ids, x, y, z, h, length=4.0, width=2.0, height=1.5, object_type=[1, 1, 2, 3])
    back = rollout_arrays(rollouts_message(arrays), "scenario_gen")
    for name in ("object_id", "x", "y", "z", "heading", "length", "width", "height", "object_type"):
        np.testing.assert_array_equal(getattr(back, name), getattr(arrays, name), err_msg=name)


def test_broadcasting_of_ids_and_sizes():
    ids, (x, y, z, h) = random_arrays()
    arrays = rollouts_from_arrays(
        "s",
        ids,
        x,
        y,
        z[0, :, :1],
        h,
        length=np.arange(1, 5)[:, None],
        width=2,
        height=[[1.0]],
        object_type=[1, 2, 3, 1],
    )
    assert arrays.object_id.shape == (3, 4) and arrays.length.shape == (3, 4, 80)
    np.testing.assert_array_equal(arrays.z[2, 1], np.full(80, z[0, 1, 0]))
    np.testing.assert_array_equal(arrays.length[1, :, 5], [1, 2, 3, 4])


@pytest.mark.parametrize(
    ("change", "message"),
    [
        # The coordinate at fault is named, whichever it is (x used to set the shape and y was blamed).
        (
            lambda a: a.update(x=a["x"][:, :, :-1]),
            r"x has shape \(3, 4, 79\), which does not broadcast to the shape of y, z, heading: \(3, 4, 80\)",
        ),
        (
            lambda a: a.update(heading=a["heading"][:, :, :-1]),
            r"heading has shape \(3, 4, 79\), which does not broadcast to the shape of x, y, z: \(3, 4, 80\)",
        ),
        (lambda a: a.update(object_id=np.array([7, 7, 1, 2])), r"scenario s rollout 0: object 7 appears 2 times"),
        (lambda a: a.update(object_id=np.array([1.0, 2.0, 3.0, 4.0])), r"object_id must be integers"),
        (lambda a: a.update(object_id=np.array([1, 2, 3])), r"object_id has shape \(3,\), expected \(4,\)"),
        (lambda a: a.update(length=np.ones(80)), r"length given without width, height, object_type"),
    ],
)
def test_bad_arrays_are_named(change, message):
    ids, (x, y, z, h) = random_arrays()
    args = {"object_id": ids, "x": x, "y": y, "z": z, "heading": h}
    change(args)
    with pytest.raises(ValueError, match=message):
        rollouts_from_arrays("s", **args)


@pytest.mark.parametrize(
    "change, message",
    [
        (
            lambda a: a.update(y=np.where(np.arange(80) == 7, np.nan, a["y"])),
            r"scenario s rollout 0 object 7: y\[7\] is not finite \(12 such value\(s\) in y\): scored as given",
        ),
        (
            lambda a: (
                a.update(length=np.ones(80), width=1, height=1, object_type=[1, 1, 1, 1])
                or a["length"].__setitem__(3, np.inf)
            ),
            r"rollout 0 object 7: length\[3\] is not finite",
        ),
    ],
)
def test_non_finite_values_are_scored_as_given_with_a_warning(change, message):
    # The official evaluator scores NaN and inf (they spread into the features): a warning, not a refusal.
    ids, (x, y, z, h) = random_arrays()
    args = {"object_id": ids, "x": x, "y": y, "z": z, "heading": h}
    change(args)
    with pytest.warns(NonFiniteValueWarning, match=message):
        rollouts = rollouts_from_arrays("s", **args)
    kept = [rollouts.y] if rollouts.length is None else [rollouts.length]
    assert not np.isfinite(kept[0]).all()


def test_zero_and_negative_sizes_are_kept_as_the_official_scores_them():
    # Logged boxes are 0 on a track's invalid steps; the official evaluator scores such sizes as given.
    ids, (x, y, z, h) = random_arrays()
    length = np.ones(80)
    length[3], length[4] = 0.0, -1.0
    arrays = rollouts_from_arrays("s", ids, x, y, z, h, length=length, width=1, height=1, object_type=0)
    np.testing.assert_array_equal(arrays.length[0, 0, 3:5], [0.0, -1.0])


def test_joint_scene_of_one_rollout():
    ids, (x, y, z, h) = random_arrays(num_rollouts=1)
    scene = joint_scene(ids, x[0], y[0], z[0], h[0])
    assert scene == protobuf_rollouts("s", ids, x, y, z, h).joint_scenes[0]


@pytest.fixture(scope="module")
def scene():
    return scenes.generate_scene(2, 1)


@pytest.mark.parametrize("challenge", ["sim_agents", "scenario_gen"])
def test_arrays_score_exactly_as_the_message(scene, challenge):
    arrays = policy_rollouts(scene, "log_replay_noise", 0, challenge)
    assert score_scenario(scene, arrays, challenge=challenge) == score_scenario(
        scene, rollouts_message(arrays), challenge=challenge
    )


def test_arrays_that_do_not_fit_the_scenario_are_refused(scene):
    arrays = policy_rollouts(scene, "constant_velocity")
    first = int(arrays.object_id[0, 0])
    fewer = rollouts_from_arrays(
        scene.scenario_id,
        arrays.object_id[:, 1:],
        arrays.x[:, 1:],
        arrays.y[:, 1:],
        arrays.z[:, 1:],
        arrays.heading[:, 1:],
    )
    with pytest.raises(ValueError, match=rf"scenario {scene.scenario_id} rollout 0: .* missing \[{first}\]"):
        score_scenario(scene, fewer)
    with pytest.raises(ValueError, match="80 steps, the scenario_gen challenge needs 91"):
        score_scenario(scene, arrays, challenge="scenario_gen")
    with pytest.raises(ValueError, match="rollouts are for scenario"):
        score_scenario(
            scene, rollouts_from_arrays("another", arrays.object_id, arrays.x, arrays.y, arrays.z, arrays.heading)
        )
