"""`waymo_open_dataset.wdl_limited.sim_agents_metrics.estimators`, without TensorFlow.

    log_likelihood = estimators.log_likelihood_estimate_timeseries(
        config.linear_speed, log_values=log_speed, sim_values=sim_speed)  # (num_objects, num_steps)
    likelihood = np.exp(log_likelihood)

Each function runs the library's own estimator (`wosac_eval.estimators.likelihoods`, the one the metrics
use) after the official checks, with the official messages. Arrays in: anything implementing `__array__`
or `__dlpack__`; out: numpy arrays answering `.numpy()`, float32 as officially (float64 from the kernel
density estimate, as the official one, whose values here are the library's, rounded through float32; no
official config uses it).
"""

from __future__ import annotations

import numpy as np

from wosac_eval.compat._arrays import ArrayIn, bool_array, compat_array, float_array, host_array
from wosac_eval.estimators import likelihoods
from wosac_eval.protos import sim_agents_metrics_pb2

_Config = sim_agents_metrics_pb2.SimAgentMetricsConfig
_ESTIMATORS = ("histogram", "kernel_density", "bernoulli")


# An empty bin without pseudo-count has a log-probability of -inf, as officially: no warning about it.
def _quiet() -> np.errstate:
    return np.errstate(divide="ignore", invalid="ignore")


def _check_batches(log_samples: np.ndarray, sim_samples: np.ndarray) -> None:
    """The official check that both samples have the same batch size (its message, then the shapes)."""
    if np.ndim(log_samples) and np.ndim(sim_samples) and log_samples.shape[0] != sim_samples.shape[0]:
        raise ValueError(
            f"Log and Sim batch sizes must be equal. (log_samples {log_samples.shape}, sim_samples {sim_samples.shape})"
        )


def histogram_estimate(config: _Config.HistogramEstimate, log_samples: ArrayIn, sim_samples: ArrayIn) -> np.ndarray:
    """Log-likelihood of each log sample under the histogram of its batch's simulated samples.

    Args:
      config: the bins (min_val, max_val, num_bins) and the additive smoothing pseudo-count.
      log_samples: float `(batch, num_log_samples)`.
      sim_samples: float `(batch, num_sim_samples)`.
    Returns:
      float32 `(batch, num_log_samples)`.
    """
    log, sim = float_array(log_samples, "log_samples"), float_array(sim_samples, "sim_samples")
    _check_batches(log, sim)
    with _quiet():
        value = likelihoods.histogram_log_likelihood(
            config.min_val, config.max_val, config.num_bins, config.additive_smoothing_pseudocount, log, sim
        )
    return compat_array(value, np.float32)


def kernel_density_estimate(
    config: _Config.KernelDensityEstimate, log_samples: ArrayIn, sim_samples: ArrayIn
) -> np.ndarray:
    """Gaussian kernel density log-likelihoods, shifted so that a Dirac sample scores 0.

    Args:
      config: the bandwidth (positive).
      log_samples: float `(batch, num_log_samples)`.
      sim_samples: float `(batch, num_sim_samples)`.
    Returns:
      float64 `(batch, num_log_samples)`, as the official (values rounded through float32).
    """
    if config.bandwidth <= 0:
        raise ValueError("Bandwidth needs to be positive for KernelDensity estimation.")
    log, sim = float_array(log_samples, "log_samples"), float_array(sim_samples, "sim_samples")
    _check_batches(log, sim)
    with _quiet():
        return compat_array(likelihoods.kernel_density_log_likelihood(config.bandwidth, log, sim), np.float64)


def bernoulli_estimate(config: _Config.BernoulliEstimate, log_samples: ArrayIn, sim_samples: ArrayIn) -> np.ndarray:
    """Log-probability of each boolean log sample under its batch's simulated frequency (with the pseudo-count).

    Args:
      config: the additive smoothing pseudo-count.
      log_samples: bool `(batch, num_log_samples)`.
      sim_samples: bool `(batch, num_sim_samples)`.
    Returns:
      float32 `(batch, num_log_samples)`.
    """
    log, sim = _bernoulli_samples(log_samples, sim_samples)
    _check_batches(log, sim)
    with _quiet():
        value = likelihoods.bernoulli_log_likelihood(config.additive_smoothing_pseudocount, log, sim)
    return compat_array(value, np.float32)


def _bernoulli_samples(log_samples: ArrayIn, sim_samples: ArrayIn) -> tuple[np.ndarray, np.ndarray]:
    """Both samples, which must be boolean (the official messages)."""
    out = []
    for value, name in ((log_samples, "log_samples"), (sim_samples, "sim_samples")):
        if host_array(value, name).dtype != bool:
            raise ValueError(f"Tensor `{name}` must be a boolean tensor for BernoulliEstimate.")
        out.append(bool_array(value, name))
    return out[0], out[1]


def _check_rank(value: np.ndarray, rank: int) -> None:
    if value.ndim != rank:
        raise ValueError(f"Tensor  must have rank {rank}.  Received rank {value.ndim}, shape {value.shape}")


def _values(feature_config: _Config.FeatureConfig, value: ArrayIn, name: str) -> np.ndarray:
    """Values as the config's estimator reads them: bool for Bernoulli (checked there), float32 otherwise."""
    if feature_config.WhichOneof("estimator") == "bernoulli":
        return host_array(value, name)
    return float_array(value, name)


def log_likelihood_estimate_timeseries(
    feature_config: _Config.FeatureConfig, log_values: ArrayIn, sim_values: ArrayIn
) -> np.ndarray:
    """Log-likelihood of each logged value of a time series under the simulated ones, as the config says
    (per object or pooled over the scene's objects, per step or pooled over steps).

    Args:
      feature_config: the feature's estimator, `independent_timesteps` and `aggregate_objects`.
      log_values: `(num_objects, num_steps)`.
      sim_values: `(num_rollouts, num_objects, num_steps)`.
    Returns:
      `(num_objects, num_steps)`, float32 (float64 for a kernel density estimate).
    """
    log, sim = _values(feature_config, log_values, "log_values"), _values(feature_config, sim_values, "sim_values")
    _check_rank(log, 2)
    _check_rank(sim, 3)
    expected = sim.shape[1:]
    if log.shape != expected:
        raise ValueError(f"Log values must be of shape: {expected} (Actual: {log.shape})")
    estimator = feature_config.WhichOneof("estimator")
    if estimator not in _ESTIMATORS:
        raise ValueError(f"`FeatureConfig` contains an invalid estimator. Found: {estimator}")
    if estimator == "bernoulli":
        _bernoulli_samples(log, sim)
    with _quiet():
        value = likelihoods.timeseries_log_likelihood(feature_config, log, sim)
    return compat_array(value, np.float64 if estimator == "kernel_density" else np.float32)


def log_likelihood_estimate_scenario_level(
    feature_config: _Config.FeatureConfig, log_values: ArrayIn, sim_values: ArrayIn
) -> np.ndarray:
    """Log-likelihood of one value per object (e.g. a rate) under the simulated ones.

    Args:
      feature_config: the feature's estimator.
      log_values: `(num_objects,)`.
      sim_values: `(num_rollouts, num_objects)`.
    Returns:
      `(num_objects,)`, float32 (float64 for a kernel density estimate).
    """
    log, sim = _values(feature_config, log_values, "log_values"), _values(feature_config, sim_values, "sim_values")
    _check_rank(log, 1)
    _check_rank(sim, 2)
    return compat_array(log_likelihood_estimate_timeseries(feature_config, log[..., None], sim[..., None])[..., 0])
