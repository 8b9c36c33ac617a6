"""The official feature and estimator functions' outputs, bit for bit, through the compat names.

`tests/data/oracle_compat/feature_functions.npz` holds made-up inputs and what waymo-open-dataset 1.6.7
returned for them (`scripts/oracle_feature_functions.py`, run with the official package): evaluated
objects that are not the first ones, several corner rounding factors, leading axes, cyclic and padded road
edges, signals on unknown lanes. The same calls through `wosac_eval.compat` give the same bits (the
kernel density estimate, computed by sklearn in float64 officially, to float32 precision).
"""

from __future__ import annotations

import numpy as np
import pytest

from support.paths import TEST_DATA
from wosac_eval.compat import (
    estimators,
    interaction_features,
    map_metric_features,
    traffic_light_features,
    trajectory_features,
)
from wosac_eval.features import interaction
from wosac_eval.features.box_geometry import box_corners
from wosac_eval.features.float32_math import packet_tail, sincos32
from wosac_eval.protos import map_pb2, sim_agents_metrics_pb2

DATA = np.load(TEST_DATA / "oracle_compat" / "feature_functions.npz")
IN = {k[3:]: DATA[k] for k in DATA.files if k.startswith("in/")}
OUT = {k[4:]: DATA[k] for k in DATA.files if k.startswith("out/")}
BOX_FIELDS = ("center_x", "center_y", "center_z", "length", "width", "height", "heading")
_Config = sim_agents_metrics_pb2.SimAgentMetricsConfig


def same_bits(actual, expected) -> None:
    actual = np.asarray(actual)
    assert actual.shape == expected.shape and actual.dtype == expected.dtype, (actual.shape, actual.dtype)
    np.testing.assert_array_equal(actual, expected)


def polylines(name: str) -> list:
    points, lengths = IN[f"{name}/points"], IN[f"{name}/lengths"]
    ends = np.cumsum(lengths)
    return [[map_pb2.MapPoint(x=x, y=y, z=z) for x, y, z in points[end - n : end]] for n, end in zip(lengths, ends)]


def test_trajectory_features_are_the_official_bits():
    series, heading, valid = IN["traj/series"], IN["traj/heading"], IN["traj/valid"]
    same_bits(trajectory_features.central_diff(series[0], pad_value=0.5), OUT["central_diff"])
    same_bits(trajectory_features.central_logical_and(valid, pad_value=True), OUT["central_logical_and"])
    ref = IN["traj/ref"]
    same_bits(trajectory_features.compute_displacement_error(*series, ref, ref * 2, ref - 1), OUT["displacement"])
    kinematics = trajectory_features.compute_kinematic_features(*series, heading=heading, seconds_per_step=0.1)
    for name, value in zip(("speed", "acceleration", "angular_speed", "angular_acceleration"), kinematics):
        same_bits(value, OUT[f"kinematics/{name}"])
    for name, value in zip(("speed", "acceleration"), trajectory_features.compute_kinematic_validity(valid)):
        same_bits(value, OUT[f"validity/{name}"])


def steps_with_other_corners(boxes: dict, factor: float) -> np.ndarray:
    """The steps where the host that made the data rounded a box corner otherwise than the golden outputs' host.

    TensorFlow computes the corners by a small matrix product, whose rounding depends on the processor (the
    golden outputs' host fuses every multiply-add; an AVX2 host, such as the one that made this file, leaves a
    few unfused). The library reproduces the golden host's corners (`box_geometry.box_corners`).
    """
    sin, cos = sincos32(boxes["heading"], packet_tail(boxes["heading"].shape))
    with interaction.corner_rounding(factor):
        radius = interaction.corner_radius(boxes["length"], boxes["width"])
    core = (boxes["length"] - np.float32(2) * radius, boxes["width"] - np.float32(2) * radius)
    corners = box_corners(boxes["center_x"], boxes["center_y"], *core, cos, sin)
    ours = np.stack([np.stack(corners[:4], -1), np.stack(corners[4:], -1)], -1)
    return (ours != OUT[f"nearest_corners/{factor}"]).any(axis=(0, 2, 3))


@pytest.mark.parametrize("factor", [0.7, 0.0, 0.3, 1.0])
def test_distance_to_nearest_object_is_the_official_bits(factor):
    boxes = {name: IN[f"boxes/{name}"] for name in BOX_FIELDS}
    distances = interaction_features.compute_distance_to_nearest_object(
        **boxes, valid=IN["boxes/valid"], evaluated_object_mask=IN["boxes/mask"], corner_rounding_factor=factor
    )
    expected = OUT[f"nearest/{factor}"]
    assert distances.shape == expected.shape and distances.dtype == expected.dtype
    # Bit for bit wherever this host's official corners are the golden host's (every step for a factor of 1,
    # where no product needs fusing); elsewhere within the corners' last bit.
    other = steps_with_other_corners(boxes, factor)
    assert not other.any() if factor == 1.0 else other.any()
    same_bits(distances[:, ~other], expected[:, ~other])
    np.testing.assert_allclose(distances, expected, rtol=0, atol=2e-6)
    assert (distances == expected).mean() > 0.8


@pytest.mark.parametrize("label", ["mask", "first"])
def test_time_to_collision_is_the_official_bits(label):
    fields = ("center_x", "center_y", "length", "width", "heading")
    following = {name: IN[f"following/{name}"] for name in fields}
    mask = IN["boxes/mask"] if label == "mask" else np.arange(10) < 7
    ttc = interaction_features.compute_time_to_collision_with_object_in_front(
        **following, valid=IN["boxes/valid"], evaluated_object_mask=mask, seconds_per_step=0.1
    )
    same_bits(ttc, OUT[f"ttc/{label}"])
    assert (ttc < interaction_features.MAXIMUM_TIME_TO_COLLISION).sum() >= 3  # some objects do follow


def test_distance_to_road_edge_is_the_official_bits():
    boxes = {name: IN[f"road/{name}"] for name in BOX_FIELDS}
    distances = map_metric_features.compute_distance_to_road_edge(
        **boxes,
        valid=IN["road/valid"],
        evaluated_object_mask=IN["boxes/mask"],
        road_edge_polylines=polylines("road_edges"),
    )
    same_bits(distances, OUT["road_edge"])
    assert (distances > 0).any() and (distances[distances > -1e9] < 0).any()  # both sides of the road
    stacked, ids = map_metric_features.tensorize_polylines(polylines("road_edges"), [7, 8, 9, 10, 11])
    same_bits(stacked, OUT["tensorize/polylines"])
    same_bits(ids, OUT["tensorize/ids"])


def test_red_light_violation_is_the_official_bits():
    signals: list[list] = [[] for _ in range(IN["red/x"].shape[1])]
    for t, lane, state, sx, sy in IN["signals"]:
        signals[int(t)].append(
            map_pb2.TrafficSignalLaneState(lane=int(lane), state=int(state), stop_point=map_pb2.MapPoint(x=sx, y=sy))
        )
    red = traffic_light_features.compute_red_light_violation(
        center_x=IN["red/x"],
        center_y=IN["red/y"],
        valid=IN["red/valid"],
        evaluated_object_mask=IN["boxes/mask"],
        lane_polylines=polylines("lanes"),
        lane_ids=IN["lanes/ids"].tolist(),
        traffic_signals=signals,
    )
    same_bits(red, OUT["red_light"])
    assert red.any()


def test_estimators_are_the_official_values():
    histogram = _Config.HistogramEstimate(min_val=-2, max_val=3, num_bins=7, additive_smoothing_pseudocount=0.1)
    log, sim = IN["est/log"], IN["est/sim"]
    same_bits(estimators.histogram_estimate(histogram, log, sim), OUT["histogram"])
    bern = _Config.BernoulliEstimate(additive_smoothing_pseudocount=0.05)
    same_bits(estimators.bernoulli_estimate(bern, log > 0, sim > 0.5), OUT["bernoulli"])
    kde = estimators.kernel_density_estimate(_Config.KernelDensityEstimate(bandwidth=0.4), log, sim)
    assert kde.dtype == np.float64
    np.testing.assert_allclose(kde, OUT["kernel_density"], rtol=1e-6, atol=1e-6)
    series_log, series_sim = IN["est/series_log"], IN["est/series_sim"]
    for independent in (False, True):
        for aggregate in (False, True):
            feature = _Config.FeatureConfig(
                histogram=histogram, independent_timesteps=independent, aggregate_objects=aggregate
            )
            key = f"{int(independent)}{int(aggregate)}"
            same_bits(
                estimators.log_likelihood_estimate_timeseries(feature, series_log, series_sim),
                OUT[f"timeseries/{key}"],
            )
            same_bits(
                estimators.log_likelihood_estimate_scenario_level(feature, series_log[:, 0], series_sim[:, :, 0]),
                OUT[f"scenario_level/{key}"],
            )
    feature = _Config.FeatureConfig(bernoulli=bern, independent_timesteps=True)
    same_bits(
        estimators.log_likelihood_estimate_timeseries(feature, series_log > 0, series_sim > 0),
        OUT["timeseries/bernoulli"],
    )
