"""Log-likelihood of logged values under the distribution of simulated values.

Histogram estimates count the simulated samples in fixed bins (with an
additive pseudo-count) and score each logged value by the log-probability of
its bin. Bernoulli estimates are two-bin histograms over booleans. With
independent timesteps, one distribution per object pools all rollouts and
steps; otherwise each (object, step) has its own distribution over rollouts.
The estimators take numpy or JAX arrays; the log-probabilities are computed in
float64 (`xp.wide_float`: under JAX, x64 on while tracing, or float32 inside
`xp.float32_precision()`).
"""
from __future__ import annotations

import numpy as np

from wosac_eval.features.xp import array_namespace, is_numpy, wide_float
from wosac_eval.protos import sim_agents_metrics_pb2

_F = np.float32
FeatureConfig = sim_agents_metrics_pb2.SimAgentMetricsConfig.FeatureConfig


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
    """Bin index of each value after clipping to the edges' range.

    Bins are closed on the left; the last bin also holds the upper edge. NaN
    values land in the last bin, as in the official histogram.

    The bin is guessed from the value's offset over the bin width, then set right by comparing the
    value with the float32 edges around the guess (the edges are rounded, the guess is off by one
    at most): the same bins as a binary search over the edges, in a few elementwise passes.
    """
    xp = array_namespace(values)
    num_bins = len(edges) - 1
    edges = xp.asarray(edges, dtype=_F)
    clipped = xp.clip(values.astype(_F), edges[0], edges[-1])
    nan = xp.isnan(clipped)
    clipped = xp.where(nan, edges[0], clipped)
    width = (edges[-1] - edges[0]) / _F(num_bins)
    guess = xp.clip(((clipped - edges[0]) / width).astype(xp.int32), 0, num_bins - 1)
    guess = guess - (clipped < xp.take(edges, guess)).astype(xp.int32)
    guess = guess + ((clipped >= xp.take(edges, guess + 1)) & (guess < num_bins - 1)).astype(xp.int32)
    return xp.where(nan, num_bins - 1, guess)


def check_batches(log_samples, sim_samples) -> None:
    """Raises ValueError naming both shapes unless both are `(batch, samples)` with the same batch.

    The official estimators refuse such inputs; broadcasting would silently
    score the wrong populations.
    """
    log_shape, sim_shape = tuple(np.shape(log_samples)), tuple(np.shape(sim_samples))
    if len(log_shape) != 2 or len(sim_shape) != 2 or log_shape[0] != sim_shape[0]:
        raise ValueError(f"log samples {log_shape} and simulated samples {sim_shape} must both be "
                         f"(batch, samples) with the same batch size")


def histogram_log_likelihood(min_val, max_val, num_bins, pseudocount,
                             log_samples: np.ndarray, sim_samples: np.ndarray, sim_weights=None) -> np.ndarray:
    """Per-population histogram log-likelihoods.

    Args:
      log_samples: `(batch, num_log_samples)`.
      sim_samples: `(batch, num_sim_samples)`.
      sim_weights: optional 0/1 `(batch, num_sim_samples)`: which simulated samples count (padding does not).
    Returns:
      float32 `(batch, num_log_samples)`.
    Raises:
      ValueError: the batch sizes differ (naming both shapes).
    """
    check_batches(log_samples, sim_samples)
    xp = array_namespace(log_samples, sim_samples)
    wide = wide_float(xp)
    edges = histogram_edges(min_val, max_val, num_bins)
    sim_bins = histogram_bins(sim_samples, edges)
    batch = sim_bins.shape[0]
    flat = (xp.arange(batch)[:, None] * num_bins + sim_bins).reshape(-1)
    # Whole counts: exact in any order. JAX needs the output length to be static.
    size = {"minlength": batch * num_bins} if is_numpy(xp) else {"length": batch * num_bins}
    weights = {} if sim_weights is None else {"weights": sim_weights.reshape(-1).astype(wide)}
    counts = xp.bincount(flat, **weights, **size).reshape(batch, num_bins)
    counts = (counts.astype(_F) + _F(pseudocount)).astype(wide)
    log_prob = xp.log(counts) - xp.log(counts.sum(axis=1, keepdims=True))
    log_bins = histogram_bins(log_samples, edges)
    return xp.take_along_axis(log_prob, log_bins, axis=1).astype(_F)


def bernoulli_log_likelihood(pseudocount, log_samples, sim_samples, sim_weights=None) -> np.ndarray:
    """Two-bin histogram over booleans: bins [-0.5, 0.5) and [0.5, 1.5]."""
    return histogram_log_likelihood(-0.5, 1.5, 2, pseudocount,
                                    log_samples.astype(_F), sim_samples.astype(_F), sim_weights)


def kernel_density_log_likelihood(bandwidth, log_samples, sim_samples, sim_weights=None) -> np.ndarray:
    """Gaussian KDE log-density, shifted so that a Dirac sample scores 0 (`sim_weights` as for histograms)."""
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


def _estimate(config: FeatureConfig, log_samples, sim_samples, sim_weights=None):
    kind = config.WhichOneof("estimator")
    if kind == "histogram":
        h = config.histogram
        return histogram_log_likelihood(h.min_val, h.max_val, h.num_bins,
                                        h.additive_smoothing_pseudocount, log_samples, sim_samples, sim_weights)
    if kind == "bernoulli":
        return bernoulli_log_likelihood(config.bernoulli.additive_smoothing_pseudocount,
                                        log_samples, sim_samples, sim_weights)
    if kind == "kernel_density":
        return kernel_density_log_likelihood(config.kernel_density.bandwidth, log_samples, sim_samples,
                                             sim_weights)
    raise ValueError(f"feature config has no estimator (got {kind!r})")


def timeseries_log_likelihood(config: FeatureConfig, log_values: np.ndarray,
                              sim_values: np.ndarray, object_mask=None) -> np.ndarray:
    """Log-likelihood of each logged value.

    Args:
      log_values: `(num_objects, num_steps)`.
      sim_values: `(num_rollouts, num_objects, num_steps)`.
      object_mask: optional bool `(num_objects,)`, the real objects: the simulated values of the others
        (padding) take no part in a distribution shared by objects (`aggregate_objects`).
    Returns:
      float32 `(num_objects, num_steps)`.
    """
    xp = array_namespace(log_values, sim_values)
    if np.ndim(sim_values) != 3:
        raise ValueError(f"simulated values must be (num_rollouts, num_objects, num_steps), got "
                         f"{tuple(np.shape(sim_values))}")
    n_rollouts, n_objects, n_steps = sim_values.shape
    if log_values.shape != (n_objects, n_steps):
        raise ValueError(f"log values {tuple(log_values.shape)} must have shape {(n_objects, n_steps)} to match "
                         f"the simulated values {tuple(sim_values.shape)}")
    if config.aggregate_objects:
        # One distribution for the whole scene (per step, or pooled over steps).
        weights = None
        if object_mask is not None:
            weights = xp.broadcast_to(object_mask[None, :, None], sim_values.shape)
        if config.independent_timesteps:
            sim = xp.transpose(sim_values, (1, 0, 2)).reshape(1, -1)
            log = log_values.T.reshape(1, -1)
            weights = None if weights is None else xp.transpose(weights, (1, 0, 2)).reshape(1, -1)
        else:
            sim = xp.transpose(sim_values, (2, 1, 0)).reshape(n_steps, -1)
            log = log_values.T
            weights = None if weights is None else xp.transpose(weights, (2, 1, 0)).reshape(n_steps, -1)
        return _estimate(config, log, sim, weights).reshape(n_steps, n_objects).T
    if config.independent_timesteps:
        sim = xp.transpose(sim_values, (1, 0, 2)).reshape(n_objects, n_rollouts * n_steps)
        log = log_values
    else:
        sim = xp.transpose(sim_values, (1, 2, 0)).reshape(n_objects * n_steps, n_rollouts)
        log = log_values.reshape(n_objects * n_steps, 1)
    return _estimate(config, log, sim).reshape(n_objects, n_steps)


def scenario_level_log_likelihood(config: FeatureConfig, log_values: np.ndarray,
                                  sim_values: np.ndarray, object_mask=None) -> np.ndarray:
    """Log-likelihood of one value per object (`(num_objects,)` vs `(num_rollouts, num_objects)`)."""
    if np.ndim(log_values) != 1 or np.ndim(sim_values) != 2 or np.shape(sim_values)[1] != np.shape(log_values)[0]:
        raise ValueError(f"log values {tuple(np.shape(log_values))} must be (num_objects,) and simulated values "
                         f"{tuple(np.shape(sim_values))} (num_rollouts, num_objects)")
    return timeseries_log_likelihood(config, log_values[:, None], sim_values[..., None], object_mask)[:, 0]
