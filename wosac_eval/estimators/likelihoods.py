"""Log-likelihood of logged values under the distribution of simulated values.

Histogram estimates count the simulated samples in fixed bins (with an
additive pseudo-count) and score each logged value by the log-probability of
its bin. Bernoulli estimates are two-bin histograms over booleans. With
independent timesteps, one distribution per object pools all rollouts and
steps; otherwise each (object, step) has its own distribution over rollouts.

The log-probabilities are the official float32 ones, bit for bit: the official
estimator builds a categorical distribution from the counts and scores a bin by
its softmax cross-entropy, so each value is log(count + pseudo-count) shifted by
the row's maximum, minus the log of the row's sum of exponentials, with
TensorFlow's CPU `log`, `exp` and summation order (`features.float32_explog`,
`features.float32_sums`). The estimators take numpy or JAX arrays.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from wosac_eval.estimators.categorical import BinCounts, log_probabilities
from wosac_eval.features.xp import array_namespace, is_numpy, wide_float
from wosac_eval.protos import sim_agents_metrics_pb2

_F = np.float32
_Config = sim_agents_metrics_pb2.SimAgentMetricsConfig
FeatureConfig = _Config.FeatureConfig
# An estimator of one batch of populations, `official_estimate`'s signature: (config, log samples, sim samples,
# sim weights or None, num_rows) -> log-likelihoods; the arrays numpy or JAX.
Estimate = Callable[[FeatureConfig, Any, Any, Any, Any], Any]


def histogram_edges(min_val: float, max_val: float, num_bins: int) -> np.ndarray:
    """`num_bins + 1` float32 edges, rounded like the official linspace.

    Interior edges are start + i * step with every operation in float32, and
    the last edge is exactly `max_val`.
    """
    start, stop = _F(min_val), _F(max_val)
    step = (stop - start) / _F(num_bins)
    interior = start + np.arange(1, num_bins, dtype=_F) * step
    return np.concatenate([[start], interior, [stop]]).astype(_F)


def histogram_bins(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin index of each value after clipping to the edges' range: int32, the values' shape.

    Bins are closed on the left; the last bin also holds the upper edge. NaN
    values land in the last bin, as in the official histogram.

    A value's bin is the number of interior edges it is not below (`_interior_edges`): below the
    first edge it is in the first bin, at the upper edge or beyond in the last, and NaN, below
    nothing, in the last too. The same bins as a binary search over the float32 edges, in one
    comparison per interior edge.
    """
    xp = array_namespace(values)
    values = xp.asarray(values, dtype=_F)
    bins = xp.zeros(values.shape, dtype=xp.int32)
    for edge in _interior_edges(edges):
        bins = bins + ~(values < edge)
    return bins


def histogram_counts(samples: Any, edges: np.ndarray, weights: Any = None) -> Any:
    """How many samples of each row fall in each bin of `histogram_bins`: `(batch, num_bins)`.

    Bin k and those before it hold the samples below interior edge k + 1, so the counts are the
    differences of those numbers, one comparison per interior edge and no bin index per sample.

    Args:
      samples: `(batch, num_samples)`.
      weights: optional 0/1 `(batch, num_samples)` in the wide float: which samples count (the
        counts are then their sums, in that float).
    """
    xp = array_namespace(samples)
    samples = xp.asarray(samples, dtype=_F)
    batch = samples.shape[0]
    if weights is None:
        total = xp.full((batch,), samples.shape[1])
    else:
        total = xp.sum(weights, axis=1)
    interior = _interior_edges(edges)
    if is_numpy(xp) and interior.size:
        below = xp.stack([_count(samples < edge, weights, xp) for edge in interior], axis=1)
    else:
        # Every edge in one pass over the samples (a compiler fuses the comparisons into the sum):
        # the same whole counts, without an array per edge.
        below = _count(samples[..., None] < interior, None if weights is None else weights[..., None], xp)
    cumulative = xp.concatenate([xp.zeros_like(total)[:, None], below.astype(total.dtype), total[:, None]], axis=1)
    return cumulative[:, 1:] - cumulative[:, :-1]


def _interior_edges(edges: np.ndarray) -> np.ndarray:
    """The edges between bins, float32 (the first and last bound the range, and clip)."""
    return np.asarray(edges, dtype=_F)[1:-1]


def _count(mask: Any, weights: Any, xp: Any) -> Any:
    """The true values of each row of `mask` (`(batch, num_values, ...)`, summed over axis 1), or the sum of
    their weights."""
    if weights is not None:
        return xp.sum(xp.where(mask, weights, 0), axis=1)
    if is_numpy(xp) and mask.shape[0] == 1:
        return np.reshape(np.count_nonzero(mask), (1,))  # numpy counts a whole array 6x faster than along an axis
    # int32 (the counts are far below 2**31): under x64 a bool sum would count in int64, twice the bytes.
    return xp.sum(mask, axis=1, dtype=np.int32)


def check_batches(log_samples: Any, sim_samples: Any) -> None:
    """Raises ValueError naming both shapes unless both are `(batch, num_samples)` with the same batch.

    The official estimators refuse such inputs; broadcasting would silently
    score the wrong populations.
    """
    log_shape, sim_shape = tuple(np.shape(log_samples)), tuple(np.shape(sim_samples))
    if len(log_shape) != 2 or len(sim_shape) != 2 or log_shape[0] != sim_shape[0]:
        raise ValueError(
            f"log samples {log_shape} and simulated samples {sim_shape} must both be "
            f"(batch, samples) with the same batch size"
        )


def histogram_bin_counts(
    histogram: _Config.HistogramEstimate,
    log_samples: np.ndarray,
    sim_samples: np.ndarray,
    sim_weights: Any = None,
    num_rows: int | None = None,
) -> BinCounts:
    """The official histogram estimate's inputs to its categorical distribution (`categorical.BinCounts`).

    Args:
      histogram: a `HistogramEstimate` (min_val, max_val, num_bins, additive_smoothing_pseudocount).
      log_samples: `(batch, num_log_samples)`.
      sim_samples: `(batch, num_sim_samples)`.
      sim_weights: optional 0/1 `(batch, num_sim_samples)`: which simulated samples count (padding does not).
      num_rows: how many leading rows are the official batch when the batch is padded (the rest
        padding), an int or a traced 0-d integer; None: all of them.
    Raises:
      ValueError: the batch sizes differ (naming both shapes).
    """
    check_batches(log_samples, sim_samples)
    xp = array_namespace(log_samples, sim_samples)
    edges = histogram_edges(histogram.min_val, histogram.max_val, histogram.num_bins)
    # Whole counts: exact in any order.
    weights = None if sim_weights is None else sim_weights.astype(wide_float(xp))
    counts = histogram_counts(sim_samples, edges, weights).astype(_F) + _F(histogram.additive_smoothing_pseudocount)
    return BinCounts(counts, histogram_bins(log_samples, edges), num_rows)


def bernoulli_bin_counts(
    bernoulli: _Config.BernoulliEstimate,
    log_samples: Any,
    sim_samples: Any,
    sim_weights: Any = None,
    num_rows: int | None = None,
) -> BinCounts:
    """The Bernoulli estimate's: a two-bin histogram over booleans, bins [-0.5, 0.5) and [0.5, 1.5]."""
    histogram = _Config.HistogramEstimate(
        min_val=-0.5, max_val=1.5, num_bins=2, additive_smoothing_pseudocount=bernoulli.additive_smoothing_pseudocount
    )
    return histogram_bin_counts(histogram, log_samples.astype(_F), sim_samples.astype(_F), sim_weights, num_rows)


def histogram_log_likelihood(
    min_val: float,
    max_val: float,
    num_bins: int,
    pseudocount: float,
    log_samples: np.ndarray,
    sim_samples: np.ndarray,
    sim_weights: Any = None,
    num_rows: int | None = None,
) -> np.ndarray:
    """Per-population histogram log-likelihoods, the official float32 values: `(batch, num_log_samples)`.

    The histogram's range, bins and pseudo-count as numbers; the rest as for `histogram_bin_counts`.
    """
    histogram = _Config.HistogramEstimate(
        min_val=min_val, max_val=max_val, num_bins=num_bins, additive_smoothing_pseudocount=pseudocount
    )
    return log_probabilities([histogram_bin_counts(histogram, log_samples, sim_samples, sim_weights, num_rows)])[0]


def bernoulli_log_likelihood(
    pseudocount: float, log_samples: Any, sim_samples: Any, sim_weights: Any = None, num_rows: int | None = None
) -> np.ndarray:
    """Per-population Bernoulli log-likelihoods, the official float32 values (see `bernoulli_bin_counts`)."""
    bernoulli = _Config.BernoulliEstimate(additive_smoothing_pseudocount=pseudocount)
    return log_probabilities([bernoulli_bin_counts(bernoulli, log_samples, sim_samples, sim_weights, num_rows)])[0]


def kernel_density_log_likelihood(
    bandwidth: float, log_samples: Any, sim_samples: Any, sim_weights: Any = None
) -> np.ndarray:
    """Gaussian KDE log-density, shifted so that a Dirac sample scores 0 (`sim_weights` as for histograms).

    The official metrics cannot score a kernel density estimate (their estimator returns float64, which
    their float32 average refuses): no official output to match. Computed in the wide float, returned
    as float32.
    """
    if bandwidth <= 0:
        raise ValueError("kernel density bandwidth must be positive")
    check_batches(log_samples, sim_samples)
    xp = array_namespace(log_samples, sim_samples)
    wide = wide_float(xp)
    diff = (log_samples[:, :, None].astype(wide) - sim_samples[:, None, :]) / bandwidth
    log_kernel = -0.5 * diff * diff
    peak = log_kernel.max(axis=-1, keepdims=True)
    if sim_weights is None:
        log_mean = xp.log(xp.mean(xp.exp(log_kernel - peak), axis=-1)) + peak[..., 0]
    else:
        w = sim_weights[:, None, :].astype(wide)
        log_kernel = xp.where(w > 0, log_kernel, -np.inf)
        peak = log_kernel.max(axis=-1, keepdims=True)
        log_mean = xp.log((xp.exp(log_kernel - peak) * w).sum(axis=-1) / w.sum(axis=-1)) + peak[..., 0]
    return log_mean.astype(_F)


@dataclasses.dataclass(frozen=True)
class Populations:
    """One feature's populations as its estimator takes them.

    Attributes:
      log: `(batch, num_log_samples)`; sim: `(batch, num_sim_samples)`.
      weights: optional 0/1 `(batch, num_sim_samples)`: which simulated samples count.
      num_rows: the official batch's rows when the batch is padded (`histogram_bin_counts`), or None.
    """

    log: Any
    sim: Any
    weights: Any = None
    num_rows: Any = None


def official_estimates(configs: Sequence[FeatureConfig], populations: Sequence[Populations]) -> list:
    """The official estimator of each config on its populations: float32 `(batch, num_log_samples)` each.

    Histograms and Bernoulli estimates are computed together (`categorical.log_probabilities`), with
    the same values as one by one.
    """
    scored: list = [None] * len(configs)
    batches, members = [], []
    for k, (config, p) in enumerate(zip(configs, populations)):
        kind = config.WhichOneof("estimator")
        if kind == "histogram":
            batches.append(histogram_bin_counts(config.histogram, p.log, p.sim, p.weights, p.num_rows))
        elif kind == "bernoulli":
            batches.append(bernoulli_bin_counts(config.bernoulli, p.log, p.sim, p.weights, p.num_rows))
        elif kind == "kernel_density":
            scored[k] = kernel_density_log_likelihood(config.kernel_density.bandwidth, p.log, p.sim, p.weights)
            continue
        else:
            raise ValueError(f"feature config has no estimator (got {kind!r})")
        members.append(k)
    for k, values in zip(members, log_probabilities(batches)):
        scored[k] = values
    return scored


def official_estimate(
    config: FeatureConfig, log_samples: Any, sim_samples: Any, sim_weights: Any = None, num_rows: int | None = None
) -> Any:
    """The official estimator of `config` on one batch of populations (`official_estimates`' one)."""
    return official_estimates([config], [Populations(log_samples, sim_samples, sim_weights, num_rows)])[0]


def populations(config: FeatureConfig, log_values: Any, sim_values: Any, object_mask: Any = None) -> Populations:
    """A feature's per-step values as the populations its config estimates.

    Args:
      log_values: `(num_objects, num_steps)`.
      sim_values: `(num_rollouts, num_objects, num_steps)`.
      object_mask: optional bool `(num_objects,)`, the real objects, first (the rest padding): the
        simulated values of the others take no part in a distribution shared by objects
        (`aggregate_objects`), and the official batch is the real objects' rows (`num_rows`).
    Raises:
      ValueError: the shapes do not match (naming both).
    """
    xp = array_namespace(log_values, sim_values)
    if np.ndim(sim_values) != 3:
        raise ValueError(
            f"simulated values must be (num_rollouts, num_objects, num_steps), got {tuple(np.shape(sim_values))}"
        )
    n_rollouts, n_objects, n_steps = sim_values.shape
    if log_values.shape != (n_objects, n_steps):
        raise ValueError(
            f"log values {tuple(log_values.shape)} must have shape {(n_objects, n_steps)} to match "
            f"the simulated values {tuple(sim_values.shape)}"
        )
    if config.aggregate_objects:
        # One distribution for the whole scene (per step, or pooled over steps).
        weights = None if object_mask is None else xp.broadcast_to(object_mask[None, :, None], sim_values.shape)
        order = (1, 0, 2) if config.independent_timesteps else (2, 1, 0)
        rows = 1 if config.independent_timesteps else n_steps
        sim = xp.transpose(sim_values, order).reshape(rows, -1)
        weights = None if weights is None else xp.transpose(weights, order).reshape(rows, -1)
        return Populations(log_values.T.reshape(rows, -1), sim, weights)
    real_objects = None if object_mask is None else object_mask.sum()
    if config.independent_timesteps:
        sim = xp.transpose(sim_values, (1, 0, 2)).reshape(n_objects, n_rollouts * n_steps)
        return Populations(log_values, sim, None, real_objects)
    sim = xp.transpose(sim_values, (1, 2, 0)).reshape(n_objects * n_steps, n_rollouts)
    real_rows = None if real_objects is None else real_objects * n_steps
    return Populations(log_values.reshape(n_objects * n_steps, 1), sim, None, real_rows)


def per_step(config: FeatureConfig, scored: Any, num_objects: int, num_steps: int) -> Any:
    """An estimator's `(batch, num_log_samples)` output for `populations(config, ...)` back as
    `(num_objects, num_steps)`."""
    if config.aggregate_objects:
        return scored.reshape(num_steps, num_objects).T
    return scored.reshape(num_objects, num_steps)


def timeseries_log_likelihoods(
    configs: Sequence[FeatureConfig],
    log_values: Sequence,
    sim_values: Sequence,
    object_mask: Any = None,
    estimate: Estimate | None = None,
) -> list:
    """`timeseries_log_likelihood` of several features (one config, log and simulated values each), at once.

    estimate: as for `timeseries_log_likelihood`; None: the official estimators, computed together
      (`official_estimates`).
    """
    inputs = [populations(c, log, sim, object_mask) for c, log, sim in zip(configs, log_values, sim_values)]
    if estimate is None:
        scored = official_estimates(configs, inputs)
    else:
        scored = [estimate(c, p.log, p.sim, p.weights, p.num_rows) for c, p in zip(configs, inputs)]
    return [per_step(c, values, *np.shape(log)) for c, values, log in zip(configs, scored, log_values)]


def timeseries_log_likelihood(
    config: FeatureConfig,
    log_values: np.ndarray,
    sim_values: np.ndarray,
    object_mask: Any = None,
    estimate: Estimate | None = None,
) -> np.ndarray:
    """Log-likelihood of each logged value.

    Args:
      log_values: `(num_objects, num_steps)`.
      sim_values: `(num_rollouts, num_objects, num_steps)`.
      object_mask: as for `populations`.
      estimate: the estimator of one batch of populations, `official_estimate`'s signature: (config, log
        `(batch, num_log_samples)`, sim `(batch, num_sim_samples)`, sim weights or None, num_rows) ->
        `(batch, num_log_samples)`; default the official one (the soft surrogate passes its own).
    Returns:
      float32 `(num_objects, num_steps)`.
    """
    return timeseries_log_likelihoods([config], [log_values], [sim_values], object_mask, estimate)[0]


def scenario_level_log_likelihood(
    config: FeatureConfig,
    log_values: np.ndarray,
    sim_values: np.ndarray,
    object_mask: Any = None,
    estimate: Estimate | None = None,
) -> np.ndarray:
    """Log-likelihood of one value per object (`(num_objects,)` vs `(num_rollouts, num_objects)`)."""
    check_scenario_level(log_values, sim_values)
    return timeseries_log_likelihood(config, log_values[:, None], sim_values[..., None], object_mask, estimate)[:, 0]


def check_scenario_level(log_values: Any, sim_values: Any) -> None:
    """Raises ValueError naming both shapes unless they are `(num_objects,)` and `(num_rollouts, num_objects)`."""
    if np.ndim(log_values) != 1 or np.ndim(sim_values) != 2 or np.shape(sim_values)[1] != np.shape(log_values)[0]:
        raise ValueError(
            f"log values {tuple(np.shape(log_values))} must be (num_objects,) and simulated values "
            f"{tuple(np.shape(sim_values))} (num_rollouts, num_objects)"
        )
