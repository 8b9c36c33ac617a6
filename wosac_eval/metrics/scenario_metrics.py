"""Per-scenario metrics: likelihoods of each feature, rates, meta-metric; aggregation and buckets.

Outputs use the official `SimAgentMetrics` field names; the metrics and their
validity masks come from `metrics.registry` (the official metrics, then any
registered beside them, scored with their own config: `registry.metric_config`). Every likelihood is
exp(mean log-likelihood) over the valid logged samples. `metric_values`
works on numpy or JAX arrays (under `jax.jit`, with x64 enabled);
`scenario_metrics` returns plain floats.
"""
from __future__ import annotations

import numpy as np

from wosac_eval.arrays.object_types import TYPE_VEHICLE
from wosac_eval.estimators import likelihoods
from wosac_eval.features.kinematics import kinematic_validity
from wosac_eval.features.metric_features import MetricFeatures
from wosac_eval.features.float32_math import split_sum32
from wosac_eval.features.xp import array_namespace, in_float32_precision, nan_spreading_min, wide_float
from wosac_eval.metrics.buckets import weighted_bucket
from wosac_eval.metrics.config import SimAgentMetricsConfig
from wosac_eval.metrics.registry import (BUCKET_FIELDS, DISPLACEMENT_FIELDS, LIKELIHOOD_FIELDS, RATE_FIELDS, RATES,
                                         active_buckets, active_likelihood_fields, active_metrics, metric_config)

_F = np.float32

# The per-scenario fields of a result, in result order.
SCENARIO_FIELDS = ("metametric", *DISPLACEMENT_FIELDS, *LIKELIHOOD_FIELDS, *RATE_FIELDS)


def scenario_fields() -> tuple[str, ...]:
    """`SCENARIO_FIELDS`, then the likelihoods of the metrics registered beside the official ones."""
    return SCENARIO_FIELDS + active_likelihood_fields()[len(LIKELIHOOD_FIELDS):]


def _weights(config) -> dict[str, float]:
    """Every active metric's meta-metric weight (a registered metric's from its own config)."""
    return {m.name: metric_config(config, m).metametric_weight for m in active_metrics()}


def _padded_sum(values, axis, dtype):
    """The sum of padded values (see `_object_mean`) along `axis` (None: all): in `dtype` (float64),
    or in JAX's float32 precision `split_sum32`, which rounds as that float64 sum nearly always does."""
    if dtype == np.float32 and in_float32_precision(array_namespace(values)):
        return split_sum32(values.reshape(-1), -1) if axis is None else split_sum32(values, axis)
    return values.sum(axis=axis, dtype=dtype)


def _masked_mean(values, valid, dtype=_F):
    xp = array_namespace(values, valid)
    total = _padded_sum(xp.where(valid, values, _F(0)), None, dtype)
    return (total / valid.sum().astype(dtype)).astype(_F)


def _any_over_time(per_step, valid):
    return (per_step & valid).any(axis=-1)


def validity_masks(log: MetricFeatures) -> dict:
    """The masks of `Metric.mask` over the logged steps, bool `(num_evaluated, num_steps)` each."""
    valid = log.valid[0]
    speed_valid, accel_valid = kinematic_validity(valid)
    is_vehicle = log.object_type[0] == TYPE_VEHICLE
    return {"valid": valid, "speed": speed_valid, "acceleration": accel_valid,
            "vehicle": valid & is_vehicle[:, None]}


def metric_log_likelihoods(config: SimAgentMetricsConfig, log: MetricFeatures, sim: MetricFeatures,
                           object_mask=None) -> dict:
    """Each metric's log-likelihoods and the mask they count under, numpy or JAX.

    object_mask: optional bool `(num_evaluated,)`, the real rows when the features are padded (padded rows
      must be invalid in `log.valid`); None: every row is real.
    Returns:
      metric name -> (log-likelihood, mask): float32 and bool `(num_evaluated,)` for an
      indicator metric (one value per object), `(num_evaluated, num_steps)` for a time series.
    """
    masks = validity_masks(log)
    out = {}
    for metric in active_metrics():
        feature_config = metric_config(config, metric)
        mask = masks[metric.mask]
        if metric.per_object:
            log_flags = _any_over_time(log.feature(metric.feature), mask)[0]
            sim_flags = _any_over_time(sim.feature(metric.feature), mask)
            ll = likelihoods.scenario_level_log_likelihood(feature_config, log_flags, sim_flags, object_mask)
            out[metric.name] = (ll, None)
        else:
            ll = likelihoods.timeseries_log_likelihood(feature_config, log.feature(metric.feature)[0],
                                                       sim.feature(metric.feature), object_mask)
            out[metric.name] = (ll, mask)
    return out


def _object_mean(values, object_mask, dtype):
    """Mean over the last axis (objects), over the real ones only when `object_mask` is given.

    With a mask (padded features) the sum runs in float64 whatever `dtype`: a float32 sum's rounding
    depends on how many padding zeros the reduction tree meets, a float64 one's does not reach float32.
    In JAX's float32 precision (`xp.wide_float`) it is `split_sum32`: as exact, in float32.
    """
    if object_mask is None:
        return values.mean(axis=-1, dtype=dtype)
    xp = array_namespace(values, object_mask)
    wide = wide_float(xp)
    total = _padded_sum(xp.where(object_mask, values, 0).astype(wide), -1, wide)
    return (total / object_mask.sum().astype(wide)).astype(dtype)


def metric_values(config: SimAgentMetricsConfig, log: MetricFeatures, sim: MetricFeatures,
                  log_likelihoods: dict | None = None, object_mask=None) -> dict:
    """Every `SCENARIO_FIELDS` value as a 0-d float32 array (the meta-metric float64), numpy or JAX.

    log_likelihoods: `metric_log_likelihoods(config, log, sim)` when already computed.
    object_mask: as for `metric_log_likelihoods`: means over objects count the real rows only.
    """
    xp = array_namespace(log.valid, sim.linear_speed)
    wide = wide_float(xp)  # float64, except in JAX's float32 precision
    masks = validity_masks(log)
    lls = metric_log_likelihoods(config, log, sim, object_mask) if log_likelihoods is None else log_likelihoods
    out = {}
    for metric in active_metrics():
        ll, mask = lls[metric.name]
        # An indicator: the mean over objects; a time series: over the valid (object, step) pairs.
        padded_sum = _F if object_mask is None else wide  # see `_object_mean`
        out[metric.output] = xp.exp(_object_mean(ll, object_mask, _F) if mask is None
                                    else _masked_mean(ll, mask, padded_sum))
    ade = sim.average_displacement_error
    per_rollout = _object_mean(ade, object_mask, _F)
    out["average_displacement_error"] = (ade.mean(dtype=_F) if object_mask is None
                                         else (_padded_sum(per_rollout.astype(wide), -1, wide)
                                               / wide(per_rollout.shape[-1])).astype(_F))
    out["min_average_displacement_error"] = nan_spreading_min(per_rollout)
    for rate in RATES:
        # int32 counts divided as float64, as officially, then stored as float32.
        flags = _any_over_time(getattr(sim, rate.feature), masks["valid"])
        out[rate.name] = (flags.mean(dtype=wide) if object_mask is None
                          else _padded_sum(_object_mean(flags, object_mask, wide), -1, wide) / wide(flags.shape[0]))
    out = {k: xp.asarray(v, _F) for k, v in out.items()}
    # The official meta-metric sums float32 likelihoods with Python floats.
    weights = _weights(config)
    out["metametric"] = sum(weights[m] * out[f"{m}_likelihood"].astype(wide) for m in weights)
    return out


def per_object_likelihoods(config: SimAgentMetricsConfig, log: MetricFeatures, sim: MetricFeatures,
                           log_likelihoods: dict | None = None, object_mask=None) -> dict:
    """Each likelihood field per evaluated object, and the weight it has in the scene's field; numpy or JAX.

    The scene's field is exp(the mean log-likelihood over its counted samples) (`metric_values`, as the
    official `_reduce_average_with_validity` / `reduce_mean`), so grouped by object it is exactly the
    count-weighted geometric mean of exp(each object's mean log-likelihood over its own counted samples):
    exp(sum_i n_i m_i / sum_i n_i) = prod_i exp(m_i) ** (n_i / sum_i n_i). A time series counts the
    object's steps under the metric's mask (`validity_masks`); an indicator one sample per object.

    log_likelihoods, object_mask: as for `metric_values`.
    Returns:
      likelihood field -> (likelihood float32 `(num_evaluated,)`, count int32 `(num_evaluated,)`):
      NaN and 0 for an object with no counted sample (a padded row; time to collision and a
      non-vehicle; an object whose log has no valid step under the mask).
    """
    xp = array_namespace(log.valid, sim.linear_speed)
    wide = wide_float(xp)  # float64, except in JAX's float32 precision
    lls = metric_log_likelihoods(config, log, sim, object_mask) if log_likelihoods is None else log_likelihoods
    out = {}
    for metric in active_metrics():
        ll, mask = lls[metric.name]
        if mask is None:  # an indicator: the object's own log-likelihood, one sample
            count = (xp.ones(ll.shape, xp.int32) if object_mask is None else object_mask.astype(xp.int32))
            mean = ll.astype(wide)
        else:
            count = mask.sum(axis=-1).astype(xp.int32)
            total = _padded_sum(xp.where(mask, ll, _F(0)).astype(wide), -1, wide)
            mean = total / xp.maximum(count, 1).astype(wide)
        out[metric.output] = (xp.where(count > 0, xp.exp(mean), wide(np.nan)).astype(_F), count)
    return out


def scenario_metrics(config: SimAgentMetricsConfig, log: MetricFeatures, sim: MetricFeatures,
                     log_likelihoods: dict | None = None) -> dict[str, float]:
    """The official per-scenario metrics from log and simulated features, as floats."""
    values = metric_values(config, log, sim, log_likelihoods)
    # The official results are stored in float32 proto fields.
    return {field: float(_F(values[field])) for field in scenario_fields()}


def aggregate_metrics(per_scenario: list[dict[str, float]]) -> dict[str, float]:
    """Mean of every field over scenarios (the official aggregation)."""
    if not per_scenario:
        raise ValueError("no scenario metrics to aggregate")
    return {f: float(_F(np.mean([m[f] for m in per_scenario])))
            for f in scenario_fields() if f in SCENARIO_FIELDS or f in per_scenario[0]}


def metametric(config: SimAgentMetricsConfig, metrics: dict[str, float]) -> float:
    """Weighted sum of the likelihoods with the config's meta-metric weights."""
    weights = _weights(config)
    return sum(weights[m] * metrics[f"{m}_likelihood"] for m in weights)


def bucket_metrics(config: SimAgentMetricsConfig, metrics: dict[str, float]) -> dict[str, float]:
    """Kinematic / interactive / map-based weighted means, plus headline figures (the official buckets)."""
    out = {"realism_meta_metric": metrics["metametric"]}
    weights = _weights(config)
    for bucket, names in active_buckets().items():
        mean = weighted_bucket(names, metrics, weights)
        if mean is None:  # the official scorer rejects the config
            raise ValueError(f"the {bucket} bucket has zero total weight in this config")
        out[f"{bucket}_metrics"] = mean
    out["min_ade"] = metrics["min_average_displacement_error"]
    for rate in RATES:
        out[rate.bucket_name] = metrics[rate.name]
    return {field: float(_F(out[field])) for field in BUCKET_FIELDS}
