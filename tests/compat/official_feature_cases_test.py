"""The official unit tests' cases of the feature modules (waymo-open-dataset's trajectory_features_test,
interaction_features_test, map_metric_features_test, traffic_light_features_test), through the compat names
only: their inputs and expected values, re-expressed with numpy. The map tests' cases of the official private
point-to-polyline distance go through the public road-edge distance, with boxes of no size at the points.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from wosac_eval.compat import (
    converters,
    interaction_features,
    trajectory_features,
)
from wosac_eval.compat import test_utils as sim_agents_test_utils

F = np.float32


def all_close(actual, expected) -> None:
    """The official tests' assertAllClose: TensorFlow's default tolerances."""
    np.testing.assert_allclose(actual, expected, rtol=1e-6, atol=1e-6)


MAX_TTC = interaction_features.MAXIMUM_TIME_TO_COLLISION
MAX_HEADING_DIFF = interaction_features.MAX_HEADING_DIFF
SMALL_HEADING_DIFF = interaction_features.MAX_HEADING_DIFF_FOR_SMALL_OVERLAP
SMALL_OVERLAP = interaction_features.SMALL_OVERLAP_THRESHOLD
BOX_KEYS = ("center_x", "center_y", "center_z", "length", "width", "height", "heading")


# --- trajectory_features ---------------------------------------------------------------------------


@pytest.mark.parametrize(("shape", "pad"), [((5,), 0.0), ((5,), 5.0), ((3, 5), 0.0), ((1,), 5.0)])
def test_central_diff_pads_a_ramp(shape, pad):
    t = np.broadcast_to(np.arange(shape[-1], dtype=F), shape)
    diff = trajectory_features.central_diff(t, pad_value=pad)
    assert diff.dtype == np.float32
    all_close(diff[..., 0], pad)
    all_close(diff[..., -1], pad)
    all_close(diff[..., 1:-1], 1.0)
    assert diff.shape[-1] == max(shape[-1], 2)  # one step: the official two pads around nothing


def test_central_diff_values():
    diff = trajectory_features.central_diff(np.array([0.0, 0.5, 1.5, 2.0, 3.5], F), pad_value=7.0)
    all_close(diff, [7.0, 0.75, 0.75, 1.0, 7.0])


@pytest.mark.parametrize(("shape", "pad"), [((5,), False), ((5,), True), ((3, 5), False)])
def test_central_logical_and_pads_all_true(shape, pad):
    result = trajectory_features.central_logical_and(np.ones(shape, bool), pad_value=pad)
    assert result.dtype == bool
    assert (result[..., 0] == pad).all() and (result[..., -1] == pad).all() and result[..., 1:-1].all()


def test_central_logical_and_values():
    result = trajectory_features.central_logical_and(np.array([True, False, True, True, False]), pad_value=True)
    np.testing.assert_array_equal(result, [True, True, False, False, True])


def test_displacement_error_shape_and_zeros():
    t = np.random.default_rng(0).random((4, 5, 3)).astype(F)
    error = trajectory_features.compute_displacement_error(*np.moveaxis(t, -1, 0), *np.moveaxis(t, -1, 0))
    assert error.shape == (4, 5)
    all_close(error, 0.0)


def test_displacement_error_refuses_unequal_shapes():
    t = np.random.default_rng(0).random((4, 5, 3)).astype(F)
    with pytest.raises(ValueError, match="Shapes of all inputs must match"):
        trajectory_features.compute_displacement_error(
            t[..., 0], t[..., 1], t[..., 2], t[..., 0], t[..., 1], np.zeros((7, 5), F)
        )


def _kinematics(states: np.ndarray, seconds_per_step: float):
    return trajectory_features.compute_kinematic_features(
        x=states[..., 0], y=states[..., 1], z=states[..., 2], heading=states[..., 3], seconds_per_step=seconds_per_step
    )


def _assert_nan_edges(speed, accel, angular_speed, angular_accel) -> None:
    for series in (speed, angular_speed):
        assert np.isnan(series[:1]).all() and np.isnan(series[-1:]).all()
    for series in (accel, angular_accel):
        assert np.isnan(series[:2]).all() and np.isnan(series[-2:]).all()


def test_kinematic_features_of_constant_speed():
    dt = 0.1
    speed = np.array([1.0, 2.0, 3.0, 5.0], F)
    states = np.array([5.0, 7.0, 11.0, 0.0], F) + np.arange(0, 2, dt, dtype=F)[:, None] * speed
    states[:, 3] = (states[:, 3] + np.pi) % (2 * np.pi) - np.pi  # wrapped headings
    linear_speed, linear_accel, angular_speed, angular_accel = _kinematics(states, dt)
    _assert_nan_edges(linear_speed, linear_accel, angular_speed, angular_accel)
    np.testing.assert_allclose(linear_speed[1:-1], np.sqrt(14.0), atol=1e-3)
    np.testing.assert_allclose(linear_accel[2:-2], 0.0, atol=1e-3)
    np.testing.assert_allclose(angular_speed[1:-1], 5.0, atol=1e-3)
    np.testing.assert_allclose(angular_accel[2:-2], 0.0, atol=1e-3)


def test_kinematic_features_of_constant_acceleration():
    dt = 0.1
    accel = np.array([1.0, 2.0, 3.0, 0.5], F)
    states = 0.5 * np.arange(0, 2, dt, dtype=F)[:, None] ** 2 * accel
    linear_speed, linear_accel, angular_speed, angular_accel = _kinematics(states.astype(F), dt)
    _assert_nan_edges(linear_speed, linear_accel, angular_speed, angular_accel)
    np.testing.assert_allclose(linear_accel[2:-2], np.sqrt(14.0), atol=1e-3)
    np.testing.assert_allclose(angular_accel[2:-2], 0.5, atol=1e-3)


def test_kinematic_features_values():
    states = np.array([[5, 0, 0, 0], [6, 0, 0, 1], [8, 0, 0, 3], [9, 0, 0, 2], [9, 0, 0, 0]], F)
    linear_speed, linear_accel, angular_speed, angular_accel = _kinematics(states, 1.0)
    _assert_nan_edges(linear_speed, linear_accel, angular_speed, angular_accel)
    all_close(linear_speed[1:-1], [1.5, 1.5, 0.5])
    all_close(linear_accel[2:-2], [-0.5])
    all_close(angular_speed[1:-1], [1.5, 0.5, -1.5])
    all_close(angular_accel[2:-2], [-1.5])


def test_kinematic_validity_values():
    validity = np.array([[1, 1, 1, 1, 1], [0, 1, 1, 0, 0], [0, 1, 0, 1, 0], [1, 0, 1, 0, 1]], bool)
    speed_valid, accel_valid = trajectory_features.compute_kinematic_validity(validity)
    assert speed_valid.shape == accel_valid.shape == validity.shape
    np.testing.assert_array_equal(speed_valid, [[0, 1, 1, 1, 0], [0, 0, 0, 0, 0], [0, 0, 1, 0, 0], [0, 1, 0, 1, 0]])
    np.testing.assert_array_equal(accel_valid, [[0, 0, 1, 0, 0], [0, 0, 0, 0, 0], [0, 0, 0, 0, 0], [0, 0, 1, 0, 0]])


# --- interaction_features --------------------------------------------------------------------------


def _boxes(all_boxes: np.ndarray) -> dict:
    """(objects, steps, 7) boxes [x, y, z, length, width, height, heading] as the functions' keywords."""
    return {key: np.ascontiguousarray(all_boxes[..., k], F) for k, key in enumerate(BOX_KEYS)}


def _first_joint_scene(scenario):
    submission = sim_agents_test_utils.load_test_submission()
    return converters.joint_scene_to_trajectories(submission.scenario_rollouts[0].joint_scenes[0], scenario)


EIGHT_OF_FIFTY = np.array([True] * 4 + [False] * 42 + [True] * 4)


def test_distance_to_nearest_object_shape(womd_test_scenario, official_testdata):
    t = _first_joint_scene(womd_test_scenario)
    distances = interaction_features.compute_distance_to_nearest_object(
        center_x=t.x,
        center_y=t.y,
        center_z=t.z,
        length=t.length,
        width=t.width,
        height=t.height,
        heading=t.heading,
        valid=t.valid,
        evaluated_object_mask=EIGHT_OF_FIFTY,
    )
    assert distances.shape == (8, t.valid.shape[-1])


def test_distance_to_nearest_object_values():
    configs = [
        [[0, 0, 0, 2, 1, 1, 0], [3, 0, 0, 4, 1, 1, 0]],  # touching ahead: 0
        [[0, 0, 0, 1, 1, 1, 0], [0, 1.5, 0, 1, 2, 1, 0]],  # touching on the side: 0
        [[0, 0, 0, 2, 1, 1, np.pi / 2], [1, 0, 0, 1, 1, 1, 0]],  # touching, the first turned 90 degrees: 0
        [[6, 0, 0, 2, 1, 1, np.pi], [-6, 0, 0, 2, 1, 1, 0]],  # 10 m apart: 10
    ]
    boxes = np.transpose(np.array(configs, F), (1, 0, 2))  # the cases as steps: (objects, steps, 7)
    distances = interaction_features.compute_distance_to_nearest_object(
        **_boxes(boxes),
        valid=np.ones(boxes.shape[:-1], bool),
        evaluated_object_mask=np.array([True, False]),
        corner_rounding_factor=0.0,
    )
    np.testing.assert_allclose(distances, [[0.0, 0.0, 0.0, 10.0]], atol=1e-6)


@pytest.mark.parametrize("other_valid", [True, False])
def test_distance_to_nearest_object_skips_invalid_objects(other_valid):
    boxes = np.array([[[6, 0, 0, 2, 1, 1, np.pi]], [[-6, 0, 0, 2, 1, 1, 0]]], F)
    distances = interaction_features.compute_distance_to_nearest_object(
        **_boxes(boxes), valid=np.array([[True], [other_valid]]), evaluated_object_mask=np.array([True, False])
    )
    all_close(distances, 10.0 if other_valid else interaction_features.EXTREMELY_LARGE_DISTANCE)


def test_distance_to_nearest_object_takes_the_nearest_valid():
    boxes = np.broadcast_to(
        np.array([[[0, 0, 0, 1, 1, 1, 0]], [[6, 0, 0, 1, 1, 1, 0]], [[0, 11, 0, 1, 1, 1, 0]]], F), (3, 3, 7)
    )
    valid = np.array([[True, True, True], [True, True, False], [True, False, True]])
    distances = interaction_features.compute_distance_to_nearest_object(
        **_boxes(boxes), valid=valid, evaluated_object_mask=np.array([True, False, False]), corner_rounding_factor=0.0
    )
    np.testing.assert_allclose(distances, [[5.0, 5.0, 10.0]], atol=1e-6)


def _circles_apart(x1, y1, r1, x2, y2, r2) -> float:
    return math.hypot(x1 - x2, y1 - y2) - r1 - r2


@pytest.mark.parametrize(
    ("factor", "expected"),
    [(0.0, 0.0), (1.0, _circles_apart(0, 0, 1, 3, 3, 2)), (0.5, _circles_apart(0.5, 0.5, 0.5, 2, 2, 1))],
)
def test_distance_to_nearest_object_rounds_the_corners(factor, expected):
    boxes = np.broadcast_to(np.array([[[0, 0, 0, 2, 2, 1, 0]], [[4, 3, 0, 6, 4, 1, 0]]], F), (2, 3, 7))
    distances = interaction_features.compute_distance_to_nearest_object(
        **_boxes(boxes),
        valid=np.ones((2, 3), bool),
        evaluated_object_mask=np.array([True, False]),
        corner_rounding_factor=factor,
    )
    np.testing.assert_allclose(distances, np.full((1, 3), expected), atol=1e-6)


def test_time_to_collision_shape(womd_test_scenario, official_testdata):
    t = _first_joint_scene(womd_test_scenario)
    ttc = interaction_features.compute_time_to_collision_with_object_in_front(
        center_x=t.x,
        center_y=t.y,
        length=t.length,
        width=t.width,
        heading=t.heading,
        valid=t.valid,
        evaluated_object_mask=EIGHT_OF_FIFTY,
        seconds_per_step=0.1,
    )
    assert ttc.shape == (8, t.valid.shape[-1])


def _closed_form(distance: float, misalignment: float, closing: float) -> float:
    """The centres' distance less the ego's half length and the turned obstacle's extent, over the closing speed."""
    return (distance - math.cos(misalignment) * 2 - math.sin(misalignment)) / closing


TTC_CASES = {
    "9 squares grid": (
        [[-3, 3], [0, 3], [3, 3], [-3, 0], [0, 0], [3, 0], [-3, -3], [0, -3], [3, -3]],
        [0] * 9,
        [[1, 1]] * 9,
        [10, 6, 1] * 3,
        [2 / 4, 2 / 5, MAX_TTC] * 3,
    ),
    "lined up rectangles": (
        [[0, 0], [5, 0], [10, 0], [15, 0]],
        [0] * 4,
        [[4, 2]] * 4,
        [6, 10, 3, 1],
        [MAX_TTC, 1 / 7, 1 / 2, MAX_TTC],
    ),
    "misaligned ignored": (
        [[0, 0], [5, 0], [10, 0], [15, 0]],
        [0, MAX_HEADING_DIFF + 0.01, 0, MAX_HEADING_DIFF - 0.01],
        [[4, 2]] * 4,
        [10, 6, 3, 1],
        [6 / 7, MAX_TTC, _closed_form(3, MAX_HEADING_DIFF - 0.01, 2), MAX_TTC],
    ),
    "no overlap ignored": (
        [[0, 0], [5, 2.1], [10, 1.1], [15, 0]],
        [0] * 4,
        [[4, 2]] * 4,
        [10, 6, 3, 1],
        [6 / 7, 1 / 3, 1 / 2, MAX_TTC],
    ),
    "small misalignment with low overlap ignored": (
        [[0, 0], [5, 2.5 - SMALL_OVERLAP], [10, -2.5 + SMALL_OVERLAP]],
        [0, SMALL_HEADING_DIFF + 0.01, -SMALL_HEADING_DIFF + 0.01],
        [[4, 2]] * 3,
        [6, 3, 1],
        [_closed_form(8, SMALL_HEADING_DIFF - 0.01, 5), MAX_TTC, MAX_TTC],
    ),
}


@pytest.mark.parametrize("case", list(TTC_CASES))
def test_time_to_collision_with_object_in_front(case):
    centres, headings, sizes, speeds, expected = (np.array(v, F) for v in TTC_CASES[case])
    dt = 0.1
    step = speeds * dt
    # One step before and one after the middle one, so that the middle step has a speed (central difference).
    x = np.stack([centres[:, 0] - step * np.cos(headings), centres[:, 0], centres[:, 0] + step * np.cos(headings)], -1)
    y = np.stack([centres[:, 1] + step * np.sin(headings), centres[:, 1], centres[:, 1] - step * np.sin(headings)], -1)
    ttc = interaction_features.compute_time_to_collision_with_object_in_front(
        center_x=x.astype(F),
        center_y=y.astype(F),
        length=np.broadcast_to(sizes[:, :1], x.shape),
        width=np.broadcast_to(sizes[:, 1:], x.shape),
        heading=np.broadcast_to(headings[:, None], x.shape),
        valid=np.ones(x.shape, bool),
        evaluated_object_mask=np.ones(len(x), bool),
        seconds_per_step=dt,
    )
    np.testing.assert_allclose(ttc[:, 1], expected, rtol=1e-6, atol=1e-6)
