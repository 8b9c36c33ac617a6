"""The metric table: every likelihood metric and event rate of a result, as a row.

A `Metric` row names a config field `X` (its estimator and meta-metric weight), the leaderboard bucket
it is weighted into, and the feature of `MetricFeatures` it scores into the output `X_likelihood`; a
`Rate` row names a simulated event rate. The official metrics are the rows of `METRICS`; a metric
registered beside them (`register_metric`, called by `features.registry.register` for a feature that
brings its own) follows them in `active_metrics`.

The table stands on the ground floor: the features (a `features.registry.Feature` carries its metric)
and the metrics (`metrics.registry` derives the result's fields and buckets from it) both read it.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

from google.protobuf import text_format

from wosac_eval.options import Mask
from wosac_eval.protos import sim_agents_metrics_pb2

BUCKETS = ("kinematic", "interactive", "map_based")


@dataclasses.dataclass(frozen=True)
class Metric:
    """One likelihood metric.

    Attributes:
      name: the config field; the output is `<name>_likelihood`.
      bucket: the leaderboard bucket it is weighted into.
      feature: the `MetricFeatures` field it scores.
      per_object: True for an indicator (did the event happen at any valid
        step: one Bernoulli sample per object), False for a per-step time series.
      mask: which logged steps count: "valid", "speed" (both neighbours
        valid), "acceleration" (two steps each side), "vehicle" (valid
        vehicles only).
      config_default: a `SimAgentMetricsConfig.FeatureConfig` textproto (e.g. `"bernoulli {}
        metametric_weight: 0.0"`): for an official metric, what a config that omits the field gets
        (`config.with_defaults`; None: omitting it is an error); for a registered one, its config.
      official: a field of the official config and result messages (`METRICS`); False for a metric
        registered beside them (`register_metric`).
    """

    name: str
    bucket: str
    feature: str
    per_object: bool
    mask: Mask | str  # a name or a member; a `Mask` once constructed (`__post_init__`)
    config_default: str | None = None
    official: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "mask", Mask.parse(self.mask))  # a mask no kernel computes is refused here

    @property
    def output(self) -> str:
        return f"{self.name}_likelihood"


@dataclasses.dataclass(frozen=True)
class Rate:
    """A simulated event rate: the share of (rollout, evaluated object) pairs with the event at a valid step."""

    name: str
    feature: str
    bucket_name: str  # its name among the leaderboard buckets (the same)
    title: str  # as the HTML report labels it


METRICS = (
    Metric(
        name="linear_speed",
        bucket="kinematic",
        feature="linear_speed",
        per_object=False,
        mask="speed",
    ),
    Metric(
        name="linear_acceleration",
        bucket="kinematic",
        feature="linear_acceleration",
        per_object=False,
        mask="acceleration",
    ),
    Metric(
        name="angular_speed",
        bucket="kinematic",
        feature="angular_speed",
        per_object=False,
        mask="speed",
    ),
    Metric(
        name="angular_acceleration",
        bucket="kinematic",
        feature="angular_acceleration",
        per_object=False,
        mask="acceleration",
    ),
    Metric(
        name="distance_to_nearest_object",
        bucket="interactive",
        feature="distance_to_nearest_object",
        per_object=False,
        mask="valid",
    ),
    Metric(
        name="collision_indication",
        bucket="interactive",
        feature="collision_per_step",
        per_object=True,
        mask="valid",
    ),
    Metric(
        name="time_to_collision",
        bucket="interactive",
        feature="time_to_collision",
        per_object=False,
        mask="vehicle",
    ),
    Metric(
        name="distance_to_road_edge",
        bucket="map_based",
        feature="distance_to_road_edge",
        per_object=False,
        mask="valid",
    ),
    Metric(
        name="offroad_indication",
        bucket="map_based",
        feature="offroad_per_step",
        per_object=True,
        mask="valid",
    ),
    # Pre-2025 configs have no traffic-light metric: it then counts as Bernoulli with weight 0.
    Metric(
        name="traffic_light_violation",
        bucket="map_based",
        feature="traffic_light_violation_per_step",
        per_object=True,
        mask="vehicle",
        config_default="bernoulli {} metametric_weight: 0.0",
    ),
)
RATES = (
    Rate(
        name="simulated_collision_rate",
        feature="collision_per_step",
        bucket_name="simulated_collision_rate",
        title="Collision rate",
    ),
    Rate(
        name="simulated_offroad_rate",
        feature="offroad_per_step",
        bucket_name="simulated_offroad_rate",
        title="Offroad rate",
    ),
    # The official rate counts red lights of every valid object, vehicle or not.
    Rate(
        name="simulated_traffic_light_violation_rate",
        feature="traffic_light_violation_per_step",
        bucket_name="simulated_traffic_light_violation_rate",
        title="Red-light violation rate",
    ),
)


# Metrics registered beside the official ones (`register_metric`), in registration order.
_REGISTERED: list[Metric] = []


def register_metric(metric: Metric) -> None:
    """Adds a non-official metric: scored with its own `config_default` after the official ones.

    Raises:
      ValueError: the name is taken, it is marked official, has no config, or its bucket is unknown.
    """
    if metric.official or metric.config_default is None:
        raise ValueError(
            f"a registered metric ({metric.name}) is not official and carries its config "
            f"(official=False, config_default=...)"
        )
    if metric.name in {m.name for m in active_metrics()}:
        raise ValueError(f"metric {metric.name!r} is already registered")
    if metric.bucket not in BUCKETS:
        raise ValueError(f"metric {metric.name!r}: bucket must be one of {', '.join(BUCKETS)}, got {metric.bucket!r}")
    default_feature_config(metric)  # a config that does not parse is refused now
    _REGISTERED.append(metric)


def unregister_metric(name: str) -> None:
    """Removes a metric added by `register_metric` (KeyError if there is none of that name)."""
    index = next((k for k, m in enumerate(_REGISTERED) if m.name == name), None)
    if index is None:
        raise KeyError(name)
    del _REGISTERED[index]


def active_metrics() -> tuple[Metric, ...]:
    """The official metrics, then the registered ones: what the scorer computes."""
    return METRICS + tuple(_REGISTERED)


def default_feature_config(metric: Metric) -> Any:
    """The metric's `config_default` as a `FeatureConfig` message (a fresh copy), or None."""
    if metric.config_default is None:
        return None
    message = _parsed_config(metric.config_default)
    return type(message).FromString(message.SerializeToString())


@functools.cache
def _parsed_config(text: str) -> Any:
    return text_format.Parse(text, sim_agents_metrics_pb2.SimAgentMetricsConfig.FeatureConfig())
