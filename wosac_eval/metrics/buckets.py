"""The weighted leaderboard buckets, computed one way for the scorer and for the result reader.

A bucket (kinematic, interactive, map-based) is the mean of its members'
likelihoods weighted by their meta-metric weights, as the official
`aggregate_metrics_to_buckets` does: the weighted likelihoods summed in member
order, divided once by the sum of the weights. The scorer applies it to the
aggregate (floats), the reader to per-scenario columns (arrays); both get the
same arithmetic, element by element.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, TypeVar

from wosac_eval.metrics.registry import METRIC_NAMES

if TYPE_CHECKING:  # the message type alone
    from wosac_eval.protos import sim_agents_metrics_pb2

Value = TypeVar("Value")  # a float, or a float64 `(num_scenarios,)` array


def metametric_weights(config: sim_agents_metrics_pb2.SimAgentMetricsConfig) -> dict[str, float]:
    """Every metric's meta-metric weight in a `SimAgentMetricsConfig` (0 for a metric it leaves unset)."""
    return {m: getattr(config, m).metametric_weight for m in METRIC_NAMES}


def weighted_bucket(
    members: tuple[str, ...], likelihoods: Mapping[str, Value], weights: Mapping[str, float]
) -> Value | None:
    """One bucket's weighted mean of likelihoods.

    Args:
      members: the bucket's metric names (`registry.METRIC_BUCKETS[bucket]`).
      likelihoods: "<metric>_likelihood" -> a float, or an array (the mean is taken element-wise).
      weights: metric name -> meta-metric weight; a metric missing counts as weight 0.
    Returns:
      The weighted mean, or None when the members' weights sum to 0: the official scorer rejects such a
      config, a reader of results leaves the bucket out.
    """
    total = sum(weights.get(m, 0.0) for m in members)
    if total == 0:
        return None
    values: Mapping[str, Any] = likelihoods  # floats or arrays: mypy types no arithmetic on a TypeVar
    return sum(weights.get(m, 0.0) * values[f"{m}_likelihood"] for m in members) / total
