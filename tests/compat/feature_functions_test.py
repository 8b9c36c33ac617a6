"""The compat feature and estimator modules as the official ones declare themselves: every public function with
its parameters (keyword-only where the official are), defaults and constants; the official messages for bad
shapes; the official shapes of short series; leading axes, each computed as one official call."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest

from support import golden
from wosac_eval.arrays.samples import sample_batch
from wosac_eval.compat import (
    estimators,
    interaction_features,
    map_metric_features,
    traffic_light_features,
    trajectory_features,
)
from wosac_eval.compat._arrays import CompatArray
from wosac_eval.protos import map_pb2, sim_agents_metrics_pb2

F = np.float32
_REQUIRED = inspect.Parameter.empty
BOXES = ["center_x", "center_y", "center_z", "length", "width", "height", "heading", "valid", "evaluated_object_mask"]
# Every public function of the official modules (waymo-open-dataset 1.6.7): its parameters in order, the
# defaults it has, and whether they are keyword-only.
OFFICIAL_SIGNATURES = {
    trajectory_features: {
        "central_diff": (["t", "pad_value"], {}, False),
        "central_logical_and": (["t", "pad_value"], {}, False),
        "compute_displacement_error": (["x", "y", "z", "ref_x", "ref_y", "ref_z"], {}, False),
        "compute_kinematic_features": (["x", "y", "z", "heading", "seconds_per_step"], {}, False),
        "compute_kinematic_validity": (["valid"], {}, False),
    },
    interaction_features: {
        "compute_distance_to_nearest_object": (
            BOXES + ["corner_rounding_factor"],
            {"corner_rounding_factor": 0.7},
            True,
        ),
        "compute_time_to_collision_with_object_in_front": (
            [
                "center_x",
                "center_y",
                "length",
                "width",
                "heading",
                "valid",
                "evaluated_object_mask",
                "seconds_per_step",
            ],
            {},
            True,
        ),
    },
    map_metric_features: {
        "compute_distance_to_road_edge": (BOXES + ["road_edge_polylines"], {}, True),
        "tensorize_polylines": (["polylines", "ids"], {"ids": None}, False),
    },
    traffic_light_features: {
        "compute_red_light_violation": (
            ["center_x", "center_y", "valid", "evaluated_object_mask", "lane_polylines", "lane_ids", "traffic_signals"],
            {},
            True,
        ),
    },
    estimators: {
        "log_likelihood_estimate_timeseries": (["feature_config", "log_values", "sim_values"], {}, False),
        "log_likelihood_estimate_scenario_level": (["feature_config", "log_values", "sim_values"], {}, False),
        "histogram_estimate": (["config", "log_samples", "sim_samples"], {}, False),
        "kernel_density_estimate": (["config", "log_samples", "sim_samples"], {}, False),
        "bernoulli_estimate": (["config", "log_samples", "sim_samples"], {}, False),
    },
}
OFFICIAL_CONSTANTS = {
    interaction_features: {
        "EXTREMELY_LARGE_DISTANCE": 1e10,
        "COLLISION_DISTANCE_THRESHOLD": 0.0,
        "CORNER_ROUNDING_FACTOR": 0.7,
        "MAX_HEADING_DIFF": math.radians(75.0),
        "MAX_HEADING_DIFF_FOR_SMALL_OVERLAP": math.radians(10.0),
        "SMALL_OVERLAP_THRESHOLD": 0.5,
        "MAXIMUM_TIME_TO_COLLISION": 5.0,
    },
    map_metric_features: {"EXTREMELY_LARGE_DISTANCE": 1e10, "OFFROAD_DISTANCE_THRESHOLD": 0.0},
    traffic_light_features: {"EXTREMELY_LARGE_DISTANCE": 1e10},
}


@pytest.mark.parametrize("module", list(OFFICIAL_SIGNATURES), ids=lambda m: m.__name__.rsplit(".", 1)[-1])
def test_every_official_function_and_constant_is_there(module):
    for name, (params, defaults, keyword_only) in OFFICIAL_SIGNATURES[module].items():
        signature = inspect.signature(getattr(module, name)).parameters
        assert list(signature) == params, name
        for param in signature.values():
            assert (param.kind == param.KEYWORD_ONLY) == keyword_only, (name, param.name)
            assert param.default == defaults.get(param.name, _REQUIRED), (name, param.name)
    for name, value in OFFICIAL_CONSTANTS.get(module, {}).items():
        assert type(getattr(module, name)) is float and getattr(module, name) == value, name


# --- the official messages ----------------------------------------------------------------------------


def _boxes(num_objects: int, num_steps: int, **changed) -> dict:
    rng = np.random.default_rng(1)
    boxes = {name: rng.uniform(0, 5, (num_objects, num_steps)).astype(F) for name in BOXES[:7]}
    boxes["valid"] = np.ones((num_objects, num_steps), bool)
    boxes["evaluated_object_mask"] = np.arange(num_objects) < 2
    return {**boxes, **changed}


EDGES = [[map_pb2.MapPoint(x=-50, y=-50), map_pb2.MapPoint(x=50, y=-50), map_pb2.MapPoint(x=50, y=50)]]


def _road(**boxes):
    return map_metric_features.compute_distance_to_road_edge(**boxes, road_edge_polylines=EDGES)


def _ttc(**boxes):
    kept = {k: v for k, v in boxes.items() if k not in ("center_z", "height")}
    return interaction_features.compute_time_to_collision_with_object_in_front(**kept, seconds_per_step=0.1)


BOX_FUNCTIONS = {
    "nearest": interaction_features.compute_distance_to_nearest_object,
    "time to collision": _ttc,
    "road edge": _road,
}


@pytest.mark.parametrize("function", list(BOX_FUNCTIONS))
def test_box_functions_refuse_what_the_official_refuse(function):
    call = BOX_FUNCTIONS[function]
    with pytest.raises(ValueError, match=r"Shapes of all inputs must match: values\[0\].shape = \[3,5\] != values"):
        call(**_boxes(3, 5, length=np.zeros((4, 5), F)))
    with pytest.raises(ValueError, match=r"not enough values to unpack \(expected 3, got 2\)"):
        call(**_boxes(3, 5, **{k: np.zeros(5, F) for k in BOXES[:7]}, valid=np.ones(5, bool)))
    # Where the official silently misaligns (a validity or a mask of another size), a clear message.
    with pytest.raises(ValueError, match="valid has shape"):
        call(**_boxes(3, 5, valid=np.ones((4, 5), bool)))
    with pytest.raises(ValueError, match="evaluated_object_mask has shape"):
        call(**_boxes(3, 5, evaluated_object_mask=np.array([True, False])))
    with pytest.raises(ValueError, match="must be a boolean array"):
        call(**_boxes(3, 5, evaluated_object_mask=np.array([1, 0, 1])))


def test_time_to_collision_of_one_step_is_refused_as_officially():
    with pytest.raises(ValueError, match=r"values\[0\].shape = \[3,1\] != values\[5\].shape = \[3,2\]"):
        _ttc(**_boxes(3, 1))


def test_road_edge_and_red_light_refuse_a_missing_map():
    with pytest.raises(ValueError, match="Missing road edges."):
        map_metric_features.compute_distance_to_road_edge(**_boxes(3, 5), road_edge_polylines=[[map_pb2.MapPoint()]])
    lanes = [[map_pb2.MapPoint(x=0, y=-9), map_pb2.MapPoint(x=0, y=9)]]
    red = {"center_x": np.zeros((2, 4)), "center_y": np.zeros((2, 4)), "valid": np.ones((2, 4), bool)}
    red["evaluated_object_mask"] = np.ones(2, bool)
    call = traffic_light_features.compute_red_light_violation
    with pytest.raises(ValueError, match="Missing lanes."):
        call(**red, lane_polylines=[], lane_ids=[], traffic_signals=[[]] * 4)
    with pytest.raises(ValueError, match="Missing traffic signals."):
        call(**red, lane_polylines=lanes, lane_ids=[1], traffic_signals=[])
    with pytest.raises(ValueError, match="Inconsistent number of lane polylines and lane ids."):
        call(**red, lane_polylines=lanes, lane_ids=[1, 2], traffic_signals=[[]] * 4)
    with pytest.raises(ValueError, match=r"Incompatible shapes: \[2,4,1\] vs. \[1,3,1\]"):
        call(**red, lane_polylines=lanes, lane_ids=[1], traffic_signals=[[]] * 3)
    assert not call(**red, lane_polylines=lanes, lane_ids=[1], traffic_signals=[[]] * 4).any()  # no signal: no red


def test_estimators_refuse_with_the_official_messages():
    config = sim_agents_metrics_pb2.SimAgentMetricsConfig
    feature = config.FeatureConfig(histogram=config.HistogramEstimate(min_val=0, max_val=1, num_bins=4))
    with pytest.raises(ValueError, match=r"Tensor  must have rank 2.  Received rank 1, shape \(4,\)"):
        estimators.log_likelihood_estimate_timeseries(feature, np.zeros(4), np.zeros((8, 4, 3)))
    with pytest.raises(ValueError, match=r"Tensor  must have rank 3.  Received rank 2, shape \(4, 3\)"):
        estimators.log_likelihood_estimate_timeseries(feature, np.zeros((4, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"Log values must be of shape: \(4, 3\) \(Actual: \(4, 2\)\)"):
        estimators.log_likelihood_estimate_timeseries(feature, np.zeros((4, 2)), np.zeros((8, 4, 3)))
    with pytest.raises(ValueError, match="`FeatureConfig` contains an invalid estimator. Found: None"):
        estimators.log_likelihood_estimate_timeseries(config.FeatureConfig(), np.zeros((4, 3)), np.zeros((8, 4, 3)))
    with pytest.raises(ValueError, match=r"Tensor  must have rank 1.  Received rank 2, shape \(4, 1\)"):
        estimators.log_likelihood_estimate_scenario_level(feature, np.zeros((4, 1)), np.zeros((8, 4)))
    bernoulli = config.FeatureConfig(bernoulli=config.BernoulliEstimate())
    with pytest.raises(ValueError, match="Tensor `sim_samples` must be a boolean tensor for BernoulliEstimate."):
        estimators.log_likelihood_estimate_timeseries(bernoulli, np.zeros((4, 3), bool), np.zeros((8, 4, 3)))


# --- shapes ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("steps", [0, 1, 2])
def test_short_series_have_the_official_two_steps(steps):
    x = np.zeros((3, steps), F)
    for feature in trajectory_features.compute_kinematic_features(x, x, x, x, seconds_per_step=0.1):
        assert feature.shape == (3, 2) and np.isnan(feature).all()
    for valid in trajectory_features.compute_kinematic_validity(np.ones((3, steps), bool)):
        assert valid.shape == (3, 2) and not valid.any()
    assert trajectory_features.central_diff(x, pad_value=4.0).tolist() == [[4.0, 4.0]] * 3


def test_results_answer_numpy_as_the_official_tensors():
    speed = trajectory_features.compute_kinematic_features(*[np.zeros((2, 6), F)] * 4, seconds_per_step=0.1)[0]
    distance = interaction_features.compute_distance_to_nearest_object(**_boxes(3, 4))
    for value in (speed, distance):
        assert isinstance(value, CompatArray) and type(value.numpy()) is np.ndarray


def _case_batch():
    """An oracle case's log and rollouts as the official code lays them out: `(samples, objects, 91)`."""
    case_set = golden.SETS[2]
    scenario, rollouts = golden.inputs(case_set, "synthetic-7-000-occlusion__wild")
    batch = sample_batch(scenario, rollouts, case_set.challenge)
    return golden.scenario(rollouts.scenario_id), batch.trajectories, batch.num_evaluated


def test_leading_axes_compute_each_sample_as_one_official_call():
    scenario, t, e = _case_batch()
    mask = np.arange(t.x.shape[1]) < e
    boxes = {"center_x": t.x, "center_y": t.y, "center_z": t.z, "length": t.length, "width": t.width}
    boxes |= {"height": t.height, "heading": t.heading, "valid": t.valid, "evaluated_object_mask": mask}
    edges = [f.road_edge.polyline for f in scenario.map_features if f.HasField("road_edge")]
    calls = {
        "nearest": lambda b: interaction_features.compute_distance_to_nearest_object(**b),
        "time to collision": lambda b: _ttc(**b),
        "road edge": lambda b: map_metric_features.compute_distance_to_road_edge(**b, road_edge_polylines=edges),
    }
    for name, call in calls.items():
        batched = call(
            {**boxes, **{k: np.stack([v[:3], v[3:6]]) for k, v in boxes.items() if k != "evaluated_object_mask"}}
        )
        assert batched.shape == (2, 3, e, t.x.shape[-1]), name
        for i in range(2):
            for j in range(3):
                one = call({k: (v if k == "evaluated_object_mask" else v[3 * i + j]) for k, v in boxes.items()})
                np.testing.assert_array_equal(batched[i, j], one, err_msg=name)


def test_the_map_tables_kept_between_calls_follow_the_polylines():
    """The segment tables are kept for the last maps (a logger calls every step with the same polylines), by
    their points: an edge moved in place gives the moved edge's distances."""
    boxes = _boxes(3, 2)
    corners = [(-50, -50), (50, -50), (50, 50)]
    edge = [map_pb2.MapPoint(x=x, y=y) for x, y in corners]
    first = map_metric_features.compute_distance_to_road_edge(**boxes, road_edge_polylines=[edge])
    again = map_metric_features.compute_distance_to_road_edge(**boxes, road_edge_polylines=[edge])
    np.testing.assert_array_equal(first, again)
    for point in edge:
        point.x -= 45.0  # moved in place, towards the boxes
    moved = map_metric_features.compute_distance_to_road_edge(**boxes, road_edge_polylines=[edge])
    fresh = [map_pb2.MapPoint(x=x - 45.0, y=y) for x, y in corners]
    np.testing.assert_array_equal(
        moved, map_metric_features.compute_distance_to_road_edge(**boxes, road_edge_polylines=[fresh])
    )
    assert (moved != first).all()
