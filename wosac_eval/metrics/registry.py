"""The metric registry: every metric, bucket and output field, in one place.

Like the official metrics package, a metric is a config field `X` (its
estimator and meta-metric weight) scored into the output `X_likelihood` from
one feature of `MetricFeatures`. The rows themselves (`Metric`, `Rate`,
`METRICS`, `RATES` and the metrics registered beside the official ones:
`register_metric`, `active_metrics`) are the metric table, `wosac_eval.metric_table`,
which the features read too; this module hands them on and derives from them
the result's fields, buckets and directions. A feature registered beside the
official ones (`features.registry.register`) brings its own metric, whose
config (estimator, bounds, weight) is its `config_default` textproto, since
the official proto has no field for it (`metric_config`). Everything that
lists metrics (the scorer, the presets, result files, compare / report, the
service) reads this module.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from wosac_eval.metric_table import (  # noqa: F401  (the registry's API: its users import these from here)
    BUCKETS,
    METRICS,
    RATES,
    Metric,
    Rate,
    active_metrics,
    default_feature_config,
    register_metric,
    unregister_metric,
)

if TYPE_CHECKING:  # the message type alone
    from wosac_eval.protos import sim_agents_metrics_pb2

METRIC_NAMES = tuple(m.name for m in METRICS)
METRIC_BUCKETS = {bucket: tuple(m.name for m in METRICS if m.bucket == bucket) for bucket in BUCKETS}
LIKELIHOOD_FIELDS = tuple(m.output for m in METRICS)
RATE_FIELDS = tuple(r.name for r in RATES)
DISPLACEMENT_FIELDS = ("average_displacement_error", "min_average_displacement_error")

# The per-scenario fields of a result (the official `SimAgentMetrics`), and whether higher is better.
SCENARIO_FIELDS: dict[str, bool] = {
    "metametric": True,
    **dict.fromkeys(LIKELIHOOD_FIELDS, True),
    **dict.fromkeys(DISPLACEMENT_FIELDS, False),
    **dict.fromkeys(RATE_FIELDS, False),
}
# The leaderboard buckets (the official `SimAgentsBucketedMetrics`), and whether higher is better.
BUCKET_FIELDS: dict[str, bool] = {
    "realism_meta_metric": True,
    **{f"{b}_metrics": True for b in BUCKETS},
    "min_ade": False,
    **{r.bucket_name: False for r in RATES},
}
# Buckets that are the mean of one per-scenario field.
BUCKET_ALIASES: dict[str, str] = {
    "realism_meta_metric": "metametric",
    "min_ade": "min_average_displacement_error",
    **{r.bucket_name: r.name for r in RATES},
}
# The weighted buckets: the config fields whose likelihoods they average.
BUCKET_MEMBERS: dict[str, tuple[str, ...]] = {f"{b}_metrics": METRIC_BUCKETS[b] for b in BUCKETS}
# The score buckets (higher is better): the headline, then the weighted buckets.
SCORE_BUCKETS = ("realism_meta_metric", *BUCKET_MEMBERS)

# Per-scenario fields and weighted buckets in display order (compare tables, report distributions): the
# headline, the weighted buckets, the likelihoods, then the displacement errors and the rates (lower is better).
DISPLAY_ORDER = (
    "metametric",
    *BUCKET_MEMBERS,
    *LIKELIHOOD_FIELDS,
    "min_average_displacement_error",
    "average_displacement_error",
    *RATE_FIELDS,
)


def active_likelihood_fields() -> tuple[str, ...]:
    return tuple(m.output for m in active_metrics())


def active_buckets() -> dict[str, tuple[str, ...]]:
    """`METRIC_BUCKETS` with the registered metrics in their buckets."""
    return {bucket: tuple(m.name for m in active_metrics() if m.bucket == bucket) for bucket in BUCKETS}


def metric_config(
    config: sim_agents_metrics_pb2.SimAgentMetricsConfig, metric: Metric
) -> sim_agents_metrics_pb2.SimAgentMetricsConfig.FeatureConfig:
    """The `FeatureConfig` a metric is scored with: the official config's field, or a registered
    metric's own `config_default` (the official proto has no field for it)."""
    return getattr(config, metric.name) if metric.official else default_feature_config(metric)


def higher_is_better(field: str) -> bool:
    """Direction of a per-scenario field or leaderboard bucket; KeyError for an unknown name."""
    if field in SCENARIO_FIELDS:
        return SCENARIO_FIELDS[field]
    return BUCKET_FIELDS[field]
