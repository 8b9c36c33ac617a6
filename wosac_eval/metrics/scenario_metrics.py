"""Per-scenario metrics: likelihoods of each feature, rates, meta-metric; aggregation and buckets.

Outputs use the official `SimAgentMetrics` field names; the metrics and their
validity masks come from `metrics.registry` (the official metrics, then any
registered beside them, scored with their own config: `registry.metric_config`). Every likelihood is
exp(mean log-likelihood) over the valid logged samples. `metric_values`
works on numpy or JAX arrays (under `jax.jit`, with x64 enabled);
`scenario_metrics` returns plain floats.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.arrays.object_types import TYPE_VEHICLE
from wosac_eval.estimators import likelihoods
from wosac_eval.features.float32_explog import libm_expf
from wosac_eval.features.float32_sums import eigen_mean32, eigen_sum32, split_sum32
from wosac_eval.features.kinematics import kinematic_validity
from wosac_eval.features.metric_features import MetricFeatures
from wosac_eval.features.xp import array_namespace, divide, in_float32_precision, nan_spreading_min, wide_float
from wosac_eval.metrics.buckets import weighted_bucket
from wosac_eval.metrics.config import SimAgentMetricsConfig
from wosac_eval.metrics.registry import (
    BUCKET_FIELDS,
    DISPLACEMENT_FIELDS,
    LIKELIHOOD_FIELDS,
    RATE_FIELDS,
    RATES,
    active_buckets,
    active_likelihood_fields,
    active_metrics,
    metric_config,
)

_F = np.float32

# The per-scenario fields of a result, in result order.
SCENARIO_FIELDS = ("metametric", *DISPLACEMENT_FIELDS, *LIKELIHOOD_FIELDS, *RATE_FIELDS)


def scenario_fields() -> tuple[str, ...]:
    """`SCENARIO_FIELDS`, then the likelihoods of the metrics registered beside the official ones."""
    return SCENARIO_FIELDS + active_likelihood_fields()[len(LIKELIHOOD_FIELDS) :]


def _weights(config: Any) -> dict[str, float]:
    """Every active metric's meta-metric weight (a registered metric's from its own config)."""
    return {m.name: metric_config(config, m).metametric_weight for m in active_metrics()}


def _padded_sum(values: Any, axis: int, dtype: Any) -> Any:
    """The sum of padded values (zeros in the padding) along `axis` (None: all): in `dtype` (float64),
    or in JAX's float32 precision `split_sum32`, which rounds as that float64 sum nearly always does."""
    if dtype == np.float32 and in_float32_precision(array_namespace(values)):
        return split_sum32(values.reshape(-1), -1) if axis is None else split_sum32(values, axis)
    return values.sum(axis=axis, dtype=dtype)


def _any_over_time(per_step: Any, valid: Any) -> Any:
    return (per_step & valid).any(axis=-1)


def validity_masks(log: MetricFeatures) -> dict:
    """The masks of `Metric.mask` over the logged steps, bool `(num_evaluated, num_steps)` each."""
    valid = log.valid[0]
    speed_valid, accel_valid = kinematic_validity(valid)
    is_vehicle = log.object_type[0] == TYPE_VEHICLE
    return {"valid": valid, "speed": speed_valid, "acceleration": accel_valid, "vehicle": valid & is_vehicle[:, None]}


def metric_log_likelihoods(
    config: SimAgentMetricsConfig, log: MetricFeatures, sim: MetricFeatures, object_mask: Any = None
) -> dict:
    """Each metric's log-likelihoods and the mask they count under, numpy or JAX.

    object_mask: optional bool `(num_evaluated,)`, the real rows when the features are padded (padded rows
      must be invalid in `log.valid`); None: every row is real.
    Returns:
      metric name -> (log-likelihood, mask): float32 and bool `(num_evaluated,)` for an
      indicator metric (one value per object), `(num_evaluated, num_steps)` for a time series.
    """
    masks = validity_masks(log)
    metrics = active_metrics()
    configs, log_values, sim_values = [], [], []
    for metric in metrics:
        configs.append(metric_config(config, metric))
        if metric.per_object:  # an indicator: whether the event happened over the valid steps, one step
            log_values.append(_any_over_time(log.feature(metric.feature), masks[metric.mask])[0][:, None])
            sim_values.append(_any_over_time(sim.feature(metric.feature), masks[metric.mask])[..., None])
        else:
            log_values.append(log.feature(metric.feature)[0])
            sim_values.append(sim.feature(metric.feature))
    # Every metric's estimate at once (`likelihoods.official_estimates`: the same values as one by one).
    scored = likelihoods.timeseries_log_likelihoods(configs, log_values, sim_values, object_mask)
    return {m.name: (ll[:, 0], None) if m.per_object else (ll, masks[m.mask]) for m, ll in zip(metrics, scored)}


def metric_values(
    config: SimAgentMetricsConfig,
    log: MetricFeatures,
    sim: MetricFeatures,
    log_likelihoods: dict | None = None,
    object_mask: Any = None,
) -> dict:
    """Every `SCENARIO_FIELDS` value as a 0-d float32 array (the meta-metric float64), numpy or JAX.

    Each is the official float32 value, bit for bit: the means over steps, objects and rollouts add in
    the official order (`eigen_sum32`) and divide once, `exp` is the C library's (`libm_expf`).

    log_likelihoods: `metric_log_likelihoods(config, log, sim)` when already computed.
    object_mask: as for `metric_log_likelihoods` (the real rows first): the means follow the
      official tensors, which hold the real rows only.
    """
    xp = array_namespace(log.valid, sim.linear_speed)
    wide = wide_float(xp)  # float64, except in JAX's float32 precision
    masks = validity_masks(log)
    lls = metric_log_likelihoods(config, log, sim, object_mask) if log_likelihoods is None else log_likelihoods
    real = None if object_mask is None else object_mask.sum()
    means = _mean_log_likelihoods([lls[m.name] for m in active_metrics()], real)
    # Each mean is a tensor of its own to the official `tf.exp`: the C library's `expf`, all at once here.
    out = dict(zip((m.output for m in active_metrics()), libm_expf(means)))
    ade = sim.average_displacement_error
    out["average_displacement_error"] = eigen_mean32(*_rollout_major(ade, real))
    out["min_average_displacement_error"] = nan_spreading_min(eigen_mean32(ade, real))
    for rate in RATES:
        # int32 counts divided as float64, as officially, then stored as float32.
        flags = _any_over_time(getattr(sim, rate.feature), masks["valid"])
        if object_mask is not None:
            flags = flags & object_mask
        counted = flags.shape[0] * (flags.shape[1] if real is None else real)
        out[rate.name] = flags.sum().astype(wide) / xp.asarray(counted).astype(wide)
    out = {k: xp.asarray(v, _F) for k, v in out.items()}
    # The official meta-metric sums float32 likelihoods with Python floats.
    weights = _weights(config)
    out["metametric"] = sum(weights[m] * out[f"{m}_likelihood"].astype(wide) for m in weights)
    return out


def _mean_log_likelihoods(scored: list, real: Any) -> Any:
    """Each metric's mean log-likelihood, float32 `(num_metrics,)`, in the official order of operations.

    An indicator is averaged over objects (`tf.reduce_mean`), a time series over its valid (object, step)
    pairs (`tf.reduce_sum` of the valid values, divided by their count). The metrics of each kind are
    reduced together: each row's sum is the same as alone.

    Args:
      scored: (log-likelihood, mask) per metric, as `metric_log_likelihoods` gives them.
      real: the number of real objects (padded rows follow), or None.
    """
    xp = array_namespace(*(ll for ll, _ in scored))
    means: list = [None] * len(scored)
    indicators = [k for k, (_, mask) in enumerate(scored) if mask is None]
    if indicators:
        rows = eigen_mean32(xp.stack([scored[k][0] for k in indicators]), real)
        for k, mean in zip(indicators, rows):
            means[k] = mean
    series = [k for k, (_, mask) in enumerate(scored) if mask is not None]
    if series:
        masked = xp.stack([xp.where(scored[k][1], scored[k][0], _F(0)) for k in series])
        steps = masked.shape[-1]
        totals = eigen_sum32(masked.reshape(len(series), -1), None if real is None else real * steps)
        counts = xp.stack([scored[k][1].sum() for k in series]).astype(_F)
        for k, mean in zip(series, divide(totals, counts)):
            means[k] = mean
    return xp.stack(means)


def _rollout_major(values: Any, real: Any) -> Any:
    """`(values flattened, count)`: a `(num_rollouts, num_objects)` array as the official tensor of its real
    objects lies in memory, rollout after rollout, followed by the padding (`real`: None, no padding)."""
    if real is None:
        return values.reshape(-1), None
    xp = array_namespace(values, real)
    rollouts, padded = values.shape
    k = xp.arange(rollouts * padded)
    per_rollout = xp.maximum(real, 1)
    position = (k // per_rollout) * padded + k % per_rollout
    counted = rollouts * real
    return xp.where(k < counted, values.reshape(-1)[xp.where(k < counted, position, 0)], _F(0)), counted


def per_object_likelihoods(
    config: SimAgentMetricsConfig,
    log: MetricFeatures,
    sim: MetricFeatures,
    log_likelihoods: dict | None = None,
    object_mask: Any = None,
) -> dict:
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
            count = xp.ones(ll.shape, xp.int32) if object_mask is None else object_mask.astype(xp.int32)
            mean = ll.astype(wide)
        else:
            count = mask.sum(axis=-1).astype(xp.int32)
            total = _padded_sum(xp.where(mask, ll, _F(0)).astype(wide), -1, wide)
            mean = total / xp.maximum(count, 1).astype(wide)
        out[metric.output] = (xp.where(count > 0, xp.exp(mean), wide(np.nan)).astype(_F), count)
    return out


def scenario_metrics(
    config: SimAgentMetricsConfig, log: MetricFeatures, sim: MetricFeatures, log_likelihoods: dict | None = None
) -> dict[str, float]:
    """The official per-scenario metrics from log and simulated features, as floats."""
    values = metric_values(config, log, sim, log_likelihoods)
    # The official results are stored in float32 proto fields.
    return {field: float(_F(values[field])) for field in scenario_fields()}


def aggregate_metrics(per_scenario: list[dict[str, float]]) -> dict[str, float]:
    """Mean of every field over scenarios (the official aggregation)."""
    if not per_scenario:
        raise ValueError("no scenario metrics to aggregate")
    return {
        f: float(_F(np.mean([m[f] for m in per_scenario])))
        for f in scenario_fields()
        if f in SCENARIO_FIELDS or f in per_scenario[0]
    }


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
