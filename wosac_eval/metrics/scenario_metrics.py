"""Per-scenario metrics: likelihoods of each feature, rates, meta-metric.

Outputs use the official `SimAgentMetrics` field names. Every likelihood is
exp(mean log-likelihood) over the valid logged samples.
"""
from __future__ import annotations

import numpy as np

from wosac_eval.estimators import likelihoods
from wosac_eval.features.kinematics import kinematic_validity
from wosac_eval.features.metric_features import MetricFeatures
from wosac_eval.metrics.config import METRIC_BUCKETS, METRIC_NAMES, SimAgentMetricsConfig

_F = np.float32
TYPE_VEHICLE = 1

SCENARIO_FIELDS = (
    "metametric", "average_displacement_error", "min_average_displacement_error",
    *(f"{m}_likelihood" for m in METRIC_NAMES),
    "simulated_collision_rate", "simulated_offroad_rate", "simulated_traffic_light_violation_rate",
)
BUCKET_FIELDS = (
    "realism_meta_metric", "kinematic_metrics", "interactive_metrics", "map_based_metrics",
    "min_ade", "simulated_collision_rate", "simulated_offroad_rate",
    "simulated_traffic_light_violation_rate",
)


def _masked_mean(values: np.ndarray, valid: np.ndarray) -> float:
    total = np.where(valid, values, _F(0)).sum(dtype=_F)
    return float(total / _F(valid.sum()))


def _any_over_time(per_step: np.ndarray, valid: np.ndarray) -> np.ndarray:
    return np.any(per_step & valid, axis=-1)


def _to_float32(value: float) -> float:
    # The official results are stored in float32 proto fields.
    return float(_F(value))


def scenario_metrics(config: SimAgentMetricsConfig, log: MetricFeatures,
                     sim: MetricFeatures) -> dict[str, float]:
    """The official per-scenario metrics from log and simulated features."""
    valid = log.valid[0]
    speed_valid, accel_valid = kinematic_validity(valid)
    is_vehicle = log.object_type[0] == TYPE_VEHICLE
    vehicle_valid = valid & is_vehicle[:, None]

    def timeseries(metric: str, feature: str, mask: np.ndarray) -> float:
        ll = likelihoods.timeseries_log_likelihood(
            getattr(config, metric), getattr(log, feature)[0], getattr(sim, feature))
        return float(np.exp(_F(_masked_mean(ll, mask))))

    def indicator(metric: str, log_flags: np.ndarray, sim_flags: np.ndarray) -> float:
        ll = likelihoods.scenario_level_log_likelihood(getattr(config, metric), log_flags, sim_flags)
        return float(np.exp(ll.mean(dtype=_F)))

    sim_collision = _any_over_time(sim.collision_per_step, log.valid)
    sim_offroad = _any_over_time(sim.offroad_per_step, log.valid)
    sim_red_light = _any_over_time(sim.traffic_light_violation_per_step, vehicle_valid)
    out = {
        "linear_speed_likelihood": timeseries("linear_speed", "linear_speed", speed_valid),
        "linear_acceleration_likelihood": timeseries("linear_acceleration", "linear_acceleration", accel_valid),
        "angular_speed_likelihood": timeseries("angular_speed", "angular_speed", speed_valid),
        "angular_acceleration_likelihood": timeseries("angular_acceleration", "angular_acceleration", accel_valid),
        "distance_to_nearest_object_likelihood": timeseries(
            "distance_to_nearest_object", "distance_to_nearest_object", valid),
        "collision_indication_likelihood": indicator(
            "collision_indication", _any_over_time(log.collision_per_step, log.valid)[0], sim_collision),
        "time_to_collision_likelihood": timeseries("time_to_collision", "time_to_collision", vehicle_valid),
        "distance_to_road_edge_likelihood": timeseries("distance_to_road_edge", "distance_to_road_edge", valid),
        "offroad_indication_likelihood": indicator(
            "offroad_indication", _any_over_time(log.offroad_per_step, log.valid)[0], sim_offroad),
        "traffic_light_violation_likelihood": indicator(
            "traffic_light_violation",
            _any_over_time(log.traffic_light_violation_per_step, vehicle_valid)[0], sim_red_light),
    }
    out = {k: _to_float32(v) for k, v in out.items()}
    ade = sim.average_displacement_error
    out["average_displacement_error"] = _to_float32(ade.mean(dtype=_F))
    out["min_average_displacement_error"] = _to_float32(ade.mean(axis=1, dtype=_F).min())
    out["simulated_collision_rate"] = _to_float32(sim_collision.mean())
    out["simulated_offroad_rate"] = _to_float32(sim_offroad.mean())
    # The official rate counts red lights of every valid object, vehicle or not.
    out["simulated_traffic_light_violation_rate"] = _to_float32(
        _any_over_time(sim.traffic_light_violation_per_step, log.valid).mean())
    out["metametric"] = _to_float32(metametric(config, out))
    return {field: out[field] for field in SCENARIO_FIELDS}


def metametric(config: SimAgentMetricsConfig, metrics: dict[str, float]) -> float:
    """Weighted sum of the likelihoods with the config's meta-metric weights."""
    return sum(getattr(config, m).metametric_weight * metrics[f"{m}_likelihood"] for m in METRIC_NAMES)


def aggregate_metrics(per_scenario: list[dict[str, float]]) -> dict[str, float]:
    """Mean of every field over scenarios (the official aggregation)."""
    if not per_scenario:
        raise ValueError("no scenario metrics to aggregate")
    return {f: _to_float32(np.mean([m[f] for m in per_scenario])) for f in SCENARIO_FIELDS}


def bucket_metrics(config: SimAgentMetricsConfig, metrics: dict[str, float]) -> dict[str, float]:
    """Kinematic / interactive / map-based weighted means, plus headline figures."""
    out = {"realism_meta_metric": metrics["metametric"]}
    for bucket, names in METRIC_BUCKETS.items():
        weights = [getattr(config, m).metametric_weight for m in names]
        if sum(weights) == 0:
            raise ValueError(f"the {bucket} bucket has zero total weight in this config")
        out[f"{bucket}_metrics"] = sum(w * metrics[f"{m}_likelihood"]
                                       for w, m in zip(weights, names)) / sum(weights)
    out["min_ade"] = metrics["min_average_displacement_error"]
    for rate in ("simulated_collision_rate", "simulated_offroad_rate",
                 "simulated_traffic_light_violation_rate"):
        out[rate] = metrics[rate]
    return {field: float(_F(out[field])) for field in BUCKET_FIELDS}
