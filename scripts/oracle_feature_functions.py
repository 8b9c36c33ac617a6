"""The official feature and estimator functions' outputs on small made-up inputs (run with the oracle's python).

    ~/.wosac-oracle/bin/python scripts/oracle_feature_functions.py OUT.npz

Writes the inputs and the official outputs (`in/...` and `out/...` entries) that
`tests/compat/oracle_functions_test.py` feeds to `wosac_eval.compat`'s functions of the same names and
compares bit for bit: every function of `trajectory_features`, `interaction_features`,
`map_metric_features`, `traffic_light_features` and `estimators`, with evaluated objects that are not
the first ones, several corner rounding factors, batched leading axes where the official functions take
them, cyclic and padded road edges, signals on unknown lanes.
"""

import sys

import numpy as np
import tensorflow as tf
from waymo_open_dataset.protos import map_pb2, sim_agents_metrics_pb2
from waymo_open_dataset.utils import box_utils
from waymo_open_dataset.wdl_limited.sim_agents_metrics import (
    estimators,
    interaction_features,
    map_metric_features,
    traffic_light_features,
    trajectory_features,
)

F = np.float32
BOX_FIELDS = ("center_x", "center_y", "center_z", "length", "width", "height", "heading")
rng = np.random.default_rng(63)
data: dict = {}


def put(kind: str, name: str, value) -> None:
    data[f"{kind}/{name}"] = np.asarray(value)


def boxes(num_objects: int, num_steps: int, spread: float) -> dict:
    """Boxes moving at random: x, y, z, length, width, height, heading float32 (objects, steps)."""
    start = rng.uniform(-spread, spread, (num_objects, 2))
    speed = rng.uniform(0, 12, num_objects)
    heading = rng.uniform(-np.pi, np.pi, num_objects)[:, None] + rng.normal(0, 0.05, (num_objects, num_steps))
    t = np.arange(num_steps) * 0.1
    x = start[:, :1] + speed[:, None] * np.cos(heading) * t
    y = start[:, 1:] + speed[:, None] * np.sin(heading) * t
    return {
        "center_x": x.astype(F),
        "center_y": y.astype(F),
        "center_z": rng.uniform(-0.5, 0.5, (num_objects, num_steps)).astype(F),
        "length": np.repeat(rng.uniform(1, 5, (num_objects, 1)), num_steps, 1).astype(F),
        "width": np.repeat(rng.uniform(0.6, 2.5, (num_objects, 1)), num_steps, 1).astype(F),
        "height": np.full((num_objects, num_steps), 1.6, F),
        "heading": np.arctan2(np.sin(heading), np.cos(heading)).astype(F),
    }


def trajectory() -> None:
    series = rng.normal(0, 3, (3, 2, 3, 12)).astype(F)  # x, y, z: (2, 3, 12) each
    heading = rng.uniform(-np.pi, np.pi, (2, 3, 12)).astype(F)
    valid = rng.random((2, 3, 12)) > 0.2
    put("in", "traj/series", series)
    put("in", "traj/heading", heading)
    put("in", "traj/valid", valid)
    put("out", "central_diff", trajectory_features.central_diff(tf.constant(series[0]), pad_value=0.5))
    put("out", "central_logical_and", trajectory_features.central_logical_and(tf.constant(valid), pad_value=True))
    ref = rng.normal(0, 3, (3, 12)).astype(F)
    put("in", "traj/ref", ref)
    put("out", "displacement", trajectory_features.compute_displacement_error(*series, ref, ref * 2, ref - 1))
    kinematics = trajectory_features.compute_kinematic_features(*series, heading=heading, seconds_per_step=0.1)
    for name, value in zip(("speed", "acceleration", "angular_speed", "angular_acceleration"), kinematics):
        put("out", f"kinematics/{name}", value)
    for name, value in zip(("speed", "acceleration"), trajectory_features.compute_kinematic_validity(valid)):
        put("out", f"validity/{name}", value)


MASK = np.array([False, True, False, True, True, False, False, False, True, False])


def interaction() -> None:
    b = boxes(10, 13, 8.0)
    valid = rng.random((10, 13)) > 0.15
    for name, value in b.items():
        put("in", f"boxes/{name}", value)
    put("in", "boxes/valid", valid)
    put("in", "boxes/mask", MASK)
    for factor in (0.7, 0.0, 0.3, 1.0):
        d = interaction_features.compute_distance_to_nearest_object(
            **b, valid=valid, evaluated_object_mask=MASK, corner_rounding_factor=factor
        )
        put("out", f"nearest/{factor}", d)
        # The official corners of the shrunk boxes (what the distances are measured between): TensorFlow's
        # small matrix product rounds some of them differently on different processors.
        shrink = np.minimum(b["length"], b["width"]) * F(factor) / F(2)
        shrunk = {**b, "length": b["length"] - F(2) * shrink, "width": b["width"] - F(2) * shrink}
        stacked = np.stack([shrunk[name] for name in BOX_FIELDS], axis=-1).reshape(-1, 7)
        corners = box_utils.get_upright_3d_box_corners(tf.constant(stacked))[:, :4, :2]
        put("out", f"nearest_corners/{factor}", tf.reshape(corners, (10, 13, 4, 2)))
    # Followers: objects in three lanes, headings near the lane's, a few going the other way.
    lane = np.repeat([0, 1], 5)
    along = np.tile([-20.0, -10.0, 0.0, 10.0, 20.0], 2) + rng.normal(0, 1, 10)
    heading = np.where(np.arange(10) == 8, np.pi, 0.0) + rng.normal(0, 0.03, 10)
    speed = rng.uniform(3, 15, 10)
    t = np.arange(13) * 0.1
    x = (along[:, None] + speed[:, None] * np.cos(heading)[:, None] * t).astype(F)
    y = (lane[:, None] * 3.5 + speed[:, None] * np.sin(heading)[:, None] * t).astype(F)
    following = {
        "center_x": x,
        "center_y": y,
        "length": b["length"],
        "width": b["width"],
        "heading": np.repeat(heading[:, None], 13, 1).astype(F),
    }
    for name, value in following.items():
        put("in", f"following/{name}", value)
    for label, mask in (("mask", MASK), ("first", np.arange(10) < 7)):
        ttc = interaction_features.compute_time_to_collision_with_object_in_front(
            **following, valid=valid, evaluated_object_mask=mask, seconds_per_step=0.1
        )
        put("out", f"ttc/{label}", ttc)


def road_edges() -> list:
    """A loop (cyclic, the road inside), a straight edge, a zigzag, one on an upper level, a lone point."""
    square = [(-20, -20, 0), (20, -20, 0), (20, 20, 0), (-20, 20, 0), (-20, -20, 0)]
    straight = [(-40, 25, 0), (40, 25, 0)]
    zigzag = [(-30, -30, 0), (-10, -26, 0), (10, -30, 0), (30, -26, 0)]
    upper = [(-5, 40, 8), (5, 40, 8), (5, -40, 8)]
    return [square, straight, zigzag, upper, [(0, 0, 0)]]


def as_points(polyline) -> list:
    return [map_pb2.MapPoint(x=x, y=y, z=z) for x, y, z in polyline]


def store_polylines(name: str, polylines) -> None:
    put("in", f"{name}/points", np.array([p for line in polylines for p in line], np.float64))
    put("in", f"{name}/lengths", np.array([len(line) for line in polylines]))


def map_features() -> None:
    edges = road_edges()
    store_polylines("road_edges", edges)
    b = boxes(10, 9, 28.0)
    b["center_z"][-2:] = 8.0  # two boxes on the upper level
    valid = rng.random((10, 9)) > 0.1
    for name, value in b.items():
        put("in", f"road/{name}", value)
    put("in", "road/valid", valid)
    distance = map_metric_features.compute_distance_to_road_edge(
        **b, valid=valid, evaluated_object_mask=MASK, road_edge_polylines=[as_points(p) for p in edges]
    )
    put("out", "road_edge", distance)
    stacked, ids = map_metric_features.tensorize_polylines([as_points(p) for p in edges], [7, 8, 9, 10, 11])
    put("out", "tensorize/polylines", stacked)
    put("out", "tensorize/ids", ids)


def traffic_lights() -> None:
    lanes = [[(x, -30, 0), (x, -5, 0), (x, 5, 0), (x, 30, 0)] for x in (0.0, 3.5, 7.0)] + [[(20, 0, 0)]]
    lane_ids = [100, 101, 102, 103]
    store_polylines("lanes", lanes)
    put("in", "lanes/ids", lane_ids)
    steps = 12
    states = []  # (step, lane, state, stop x, stop y)
    for t in range(steps):
        states += [(t, 100, 4 if t < 8 else 6, 0.0, 0.5), (t, 101, 1, 3.5, -0.25), (t, 999, 4, 50.0, 0.0)]
        if t % 3 == 0:
            states.append((t, 102, 4, 7.0, 1.0))
    put("in", "signals", np.array(states, np.float64))
    signals = [[] for _ in range(steps)]
    for t, lane, state, sx, sy in states:
        signals[int(t)].append(
            map_pb2.TrafficSignalLaneState(lane=int(lane), state=int(state), stop_point=map_pb2.MapPoint(x=sx, y=sy))
        )
    x = np.repeat(np.array([0.0, 3.5, 7.0, 0.1, 3.4, 7.1, 0.0, 3.5, 7.0, 20.0])[:, None], steps, 1)
    y = rng.uniform(-8, -2, (10, 1)) + rng.uniform(0.5, 1.5, (10, 1)) * np.arange(steps)
    valid = rng.random((10, steps)) > 0.1
    put("in", "red/x", x.astype(F))
    put("in", "red/y", y.astype(F))
    put("in", "red/valid", valid)
    red = traffic_light_features.compute_red_light_violation(
        center_x=x.astype(F),
        center_y=y.astype(F),
        valid=valid,
        evaluated_object_mask=MASK,
        lane_polylines=[as_points(p) for p in lanes],
        lane_ids=lane_ids,
        traffic_signals=signals,
    )
    put("out", "red_light", red)


def estimator_outputs() -> None:
    config = sim_agents_metrics_pb2.SimAgentMetricsConfig
    histogram = config.HistogramEstimate(min_val=-2, max_val=3, num_bins=7, additive_smoothing_pseudocount=0.1)
    log, sim = rng.normal(0, 1.5, (4, 6)).astype(F), rng.normal(0.3, 1.2, (4, 20)).astype(F)
    put("in", "est/log", log)
    put("in", "est/sim", sim)
    put("out", "histogram", estimators.histogram_estimate(histogram, log, sim))
    bern = config.BernoulliEstimate(additive_smoothing_pseudocount=0.05)
    put("out", "bernoulli", estimators.bernoulli_estimate(bern, log > 0, sim > 0.5))
    put(
        "out",
        "kernel_density",
        estimators.kernel_density_estimate(config.KernelDensityEstimate(bandwidth=0.4), log, sim),
    )
    series_log, series_sim = rng.normal(0, 1, (5, 9)).astype(F), rng.normal(0, 1, (8, 5, 9)).astype(F)
    put("in", "est/series_log", series_log)
    put("in", "est/series_sim", series_sim)
    for independent in (False, True):
        for aggregate in (False, True):
            feature = config.FeatureConfig(
                histogram=histogram, independent_timesteps=independent, aggregate_objects=aggregate
            )
            name = f"timeseries/{int(independent)}{int(aggregate)}"
            put("out", name, estimators.log_likelihood_estimate_timeseries(feature, series_log, series_sim))
            flat = estimators.log_likelihood_estimate_scenario_level(feature, series_log[:, 0], series_sim[:, :, 0])
            put("out", f"scenario_level/{int(independent)}{int(aggregate)}", flat)
    feature = config.FeatureConfig(bernoulli=bern, independent_timesteps=True)
    put(
        "out",
        "timeseries/bernoulli",
        estimators.log_likelihood_estimate_timeseries(feature, series_log > 0, series_sim > 0),
    )


def main(out_path: str) -> None:
    trajectory()
    interaction()
    map_features()
    traffic_lights()
    estimator_outputs()
    np.savez_compressed(out_path, **data)
    print(out_path, len(data), "arrays")


if __name__ == "__main__":
    main(*sys.argv[1:])
