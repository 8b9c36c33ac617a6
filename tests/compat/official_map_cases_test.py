"""The official unit tests' cases of map_metric_features and traffic_light_features, through the compat names.

The official map tests check the private point-to-polylines distance (`_compute_signed_distance_to_polylines`)
directly; here the same points and polylines go through the public `compute_distance_to_road_edge`, each
point a box of no size (its four corners at the point, its bottom at the point's height), with the public
function's 3x vertical stretch, which picks the same polylines in every case.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from wosac_eval.compat import converters, map_metric_features, traffic_light_features, trajectory_utils
from wosac_eval.compat import test_utils as sim_agents_test_utils
from wosac_eval.protos import map_pb2

F = np.float32


def all_close(actual, expected) -> None:
    """The official tests' assertAllClose: TensorFlow's default tolerances."""
    np.testing.assert_allclose(actual, expected, rtol=1e-6, atol=1e-6)


EIGHT_OF_FIFTY = np.array([True] * 4 + [False] * 42 + [True] * 4)


def _points(rows) -> list:
    """Map points from (x, y, z[, valid]) rows; rows flagged invalid (the official padding) are left out."""
    return [map_pb2.MapPoint(x=r[0], y=r[1], z=r[2]) for r in np.asarray(rows, float) if len(r) < 4 or r[3]]


def _signed_distances(xyz, polylines) -> np.ndarray:
    """Signed distance of each point to the road edges: the points as boxes of no size."""
    xyz = np.asarray(xyz, F)
    zeros = np.zeros((len(xyz), 1), F)
    distances = map_metric_features.compute_distance_to_road_edge(
        center_x=xyz[:, :1],
        center_y=xyz[:, 1:2],
        center_z=xyz[:, 2:],
        length=zeros,
        width=zeros,
        height=zeros,
        heading=zeros,
        valid=np.ones((len(xyz), 1), bool),
        evaluated_object_mask=np.ones(len(xyz), bool),
        road_edge_polylines=[_points(p) for p in polylines],
    )
    return distances[:, 0]


def _grid(low: float, high: float, n: int) -> np.ndarray:
    x = np.linspace(low, high, n, dtype=F)
    return np.stack(np.meshgrid(x, x), axis=-1).reshape(-1, 2)


def _at_height(xy: np.ndarray, z: float) -> np.ndarray:
    return np.concatenate([xy, np.full((len(xy), 1), z, F)], axis=-1)


def _road_edges(scenario) -> list:
    return [f.road_edge.polyline for f in scenario.map_features if f.HasField("road_edge")]


def _first_joint_scene(scenario):
    submission = sim_agents_test_utils.load_test_submission()
    return converters.joint_scene_to_trajectories(submission.scenario_rollouts[0].joint_scenes[0], scenario)


def _road_distance(t, road_edges):
    return map_metric_features.compute_distance_to_road_edge(
        center_x=t.x,
        center_y=t.y,
        center_z=t.z,
        length=t.length,
        width=t.width,
        height=t.height,
        heading=t.heading,
        valid=t.valid,
        evaluated_object_mask=EIGHT_OF_FIFTY,
        road_edge_polylines=road_edges,
    )


def test_distance_to_road_edge_shape(womd_test_scenario, official_testdata):
    t = _first_joint_scene(womd_test_scenario)
    assert _road_distance(t, _road_edges(womd_test_scenario)).shape == (8, t.valid.shape[-1])


def test_distance_to_road_edge_refuses_a_missing_map(womd_test_scenario, official_testdata):
    with pytest.raises(ValueError, match="Missing road edges."):
        _road_distance(_first_joint_scene(womd_test_scenario), [])


def test_signed_distance_sign():
    # The edge runs up the y axis: the road on its left (negative), off the road on its right.
    distances = _signed_distances([[-1, 1, 0], [2, 1, 0]], [[[0, 0, 0, 1], [0, 2, 0, 1]]])
    all_close(distances, [-1.0, 2.0])


def test_signed_distance_magnitude():
    distances = _signed_distances([[0, 1, 0], [3, -1, 0]], [[[0, 0, 0, 1], [2, 0, 0, 1]]])
    all_close(np.abs(distances), [1.0, math.sqrt(2)])


def test_signed_distance_to_a_circle():
    radius = 1.2
    grid = _grid(-2 * radius, 2 * radius, 10)
    t = np.linspace(0, 1, 41, dtype=F)
    circle = np.stack([np.cos(t * 2 * np.pi) * radius, np.sin(t * 2 * np.pi) * radius, 0 * t, 1 + 0 * t], -1)
    distances = _signed_distances(_at_height(grid, 0), [circle])
    np.testing.assert_allclose(distances, np.linalg.norm(grid, axis=-1) - radius, rtol=0.02, atol=0.01)


def test_signed_distance_to_a_square():
    side = 0.8
    grid = _grid(-2, 2, 10)
    square = np.array([[1, 1, 0, 1], [-1, 1, 0, 1], [-1, -1, 0, 1], [1, -1, 0, 1], [1, 1, 0, 1]], F) * [
        side,
        side,
        1,
        1,
    ]
    distances = _signed_distances(_at_height(grid, 0), [square])
    d = np.abs(grid) - side
    expected = np.linalg.norm(np.maximum(d, 0), axis=-1) + np.minimum(d.max(axis=-1), 0)
    np.testing.assert_allclose(distances, expected, rtol=1e-6, atol=1e-6)


TWO_LINES = [[[0, 10, 0, 1], [0, -10, 0, 1]], [[2, -10, 0, 1], [2, 10, 0, 1]]]
PADDED_LINES = [
    [[0, 10, 0, 1], [0, 3, 0, 1], [0, -3, 0, 1], [0, -10, 0, 1]],
    [[2, -10, 0, 1], [2, 10, 0, 1], [0, 0, 0, 0], [0, 0, 0, 0]],  # two points, then padding
]


@pytest.mark.parametrize("lines", [TWO_LINES, PADDED_LINES], ids=["two lines", "padded lines"])
def test_signed_distance_between_two_lines(lines):
    grid = _grid(-1, 4, 10)
    distances = _signed_distances(_at_height(grid, 0), lines)
    np.testing.assert_allclose(distances, np.abs(grid[:, 0] - 1) - 1, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize(("n", "points_z", "lines_z"), [(10, 8.0, 10.0), (100, 1.0, 3.0)], ids=["far", "close"])
def test_signed_distance_picks_the_edge_at_the_points_height(n, points_z, lines_z):
    grid = _grid(-1, 4, n)
    points = np.concatenate([_at_height(grid, -points_z), _at_height(grid, points_z)])
    lines = [[[0, -10, -lines_z, 1], [0, 10, -lines_z, 1]], [[-10, 0, lines_z, 1], [10, 0, lines_z, 1]]]
    distances = _signed_distances(points, lines)
    np.testing.assert_allclose(distances, np.concatenate([grid[:, 0], -grid[:, 1]]), rtol=1e-6, atol=1e-6)


def test_tensorize_polylines_pads_and_keeps_ids():
    lines = [_points([[0, 0, 0], [1, 1, 1]]), _points([[5, 5, 5]]), _points([[2, 2, 2], [3, 3, 3], [4, 4, 4]])]
    stacked, ids = map_metric_features.tensorize_polylines(lines, [7, 8, 9])
    assert stacked.dtype == np.float32 and stacked.shape == (2, 3, 4) and ids.dtype == np.int32
    np.testing.assert_array_equal(ids, [7, 9])  # the one-point polyline is left out, with its id
    np.testing.assert_array_equal(stacked[0, :, 3], [1, 1, 0])
    with pytest.raises(ValueError, match="Inconsistent number of polylines and ids."):
        map_metric_features.tensorize_polylines(lines, [1])


# --- traffic_light_features -------------------------------------------------------------------------


def test_red_light_violation_of_the_moved_sdc(womd_test_scenario):
    scenario = womd_test_scenario
    t = trajectory_utils.ObjectTrajectories.from_scenario(scenario)
    # The SDC waits at a red light: moved towards it (negative y) from step 20 on, it runs the light.
    y = np.array(t.y)
    y[scenario.sdc_track_index, 20:] -= np.arange(71)
    mask = np.zeros(83, bool)
    mask[[42, 43, 72, 82]] = True
    surface = map_pb2.LaneCenter.LaneType.TYPE_SURFACE_STREET
    lanes = [f for f in scenario.map_features if f.HasField("lane") and f.lane.type == surface]
    violations = traffic_light_features.compute_red_light_violation(
        center_x=t.x,
        center_y=y,
        valid=t.valid,
        evaluated_object_mask=mask,
        lane_polylines=[f.lane.polyline for f in lanes],
        lane_ids=[f.id for f in lanes],
        traffic_signals=[list(state.lane_states) for state in scenario.dynamic_map_states],
    )
    assert violations.shape == (4, t.valid.shape[-1])
    assert violations.any(axis=-1)[-1]  # the SDC, the last evaluated object
    assert not violations[:-1].any()
