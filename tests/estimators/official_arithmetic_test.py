"""The estimators and the metrics' averages give the official float32 values bit for bit.

Against the official arithmetic's answers (`tests/data/oracle_arithmetic`): the official
`histogram_estimate` (NaN samples, empty bins with no pseudo-count), `bernoulli_estimate`,
`log_likelihood_estimate_timeseries` under agent- and scene-level configs with independent and
dependent timesteps, and the metrics' average over valid entries followed by `tf.exp`; each alone and
all together (`official_estimates` scores a scenario's metrics at once).
"""

from __future__ import annotations

import numpy as np
import pytest

from support import oracle_arithmetic as oracle
from wosac_eval.estimators import likelihoods
from wosac_eval.features.float32_explog import libm_expf
from wosac_eval.features.float32_sums import eigen_sum32
from wosac_eval.protos import sim_agents_metrics_pb2

Config = sim_agents_metrics_pb2.SimAgentMetricsConfig


def histogram_case(key: str):
    c = oracle.case("histogram", key)
    low, high, bins, pseudocount = c["config"]
    config = Config.FeatureConfig()
    config.histogram.min_val, config.histogram.max_val = low, high
    config.histogram.num_bins, config.histogram.additive_smoothing_pseudocount = int(bins), pseudocount
    return config, c


def bernoulli_case(key: str):
    c = oracle.case("bernoulli", key)
    config = Config.FeatureConfig()
    config.bernoulli.additive_smoothing_pseudocount = float(c["pseudocount"])
    return config, c


@pytest.mark.parametrize("key", oracle.keys("histogram"))
def test_histogram_estimate_is_the_official(key):
    config, c = histogram_case(key)
    h = config.histogram
    got = likelihoods.histogram_log_likelihood(
        h.min_val, h.max_val, h.num_bins, h.additive_smoothing_pseudocount, c["log"], c["sim"]
    )
    oracle.assert_bits_equal(got, c["out"], f"histogram {key}")


@pytest.mark.parametrize("key", oracle.keys("bernoulli"))
def test_bernoulli_estimate_is_the_official(key):
    config, c = bernoulli_case(key)
    got = likelihoods.bernoulli_log_likelihood(config.bernoulli.additive_smoothing_pseudocount, c["log"], c["sim"])
    oracle.assert_bits_equal(got, c["out"], f"bernoulli {key}")


def test_estimates_together_are_the_same_as_alone():
    """`official_estimates` of every histogram and Bernoulli case at once, rows of the same widths mixed."""
    pairs = [histogram_case(k) for k in oracle.keys("histogram")] + [
        bernoulli_case(k) for k in oracle.keys("bernoulli")
    ]
    populations = [likelihoods.Populations(c["log"], c["sim"]) for _, c in pairs]
    for (_, c), got in zip(pairs, likelihoods.official_estimates([config for config, _ in pairs], populations)):
        oracle.assert_bits_equal(got, c["out"], "together")


@pytest.mark.parametrize("key", oracle.keys("timeseries"))
def test_timeseries_estimate_is_the_official(key):
    c = oracle.case("timeseries", key)
    config = Config.FeatureConfig.FromString(c["config"].tobytes())
    oracle.assert_bits_equal(likelihoods.timeseries_log_likelihood(config, c["log"], c["sim"]), c["out"], key)
    # The same behind padding objects, named by the object mask (the JAX backends' layout).
    n_rollouts, n_objects, n_steps = c["sim"].shape
    log = np.concatenate([c["log"], np.full((3, n_steps), 0.5, np.float32)])
    sim = np.concatenate([c["sim"], np.full((n_rollouts, 3, n_steps), 0.5, np.float32)], axis=1)
    mask = np.arange(n_objects + 3) < n_objects
    padded = likelihoods.timeseries_log_likelihood(config, log, sim, object_mask=mask)
    oracle.assert_bits_equal(padded[:n_objects], c["out"], f"{key} padded")


@pytest.mark.parametrize("key", oracle.keys("masked_mean"))
def test_the_metrics_average_then_exp_is_the_official(key):
    c = oracle.case("masked_mean", key)
    values, valid = c["values"], c["valid"]
    total = eigen_sum32(np.where(valid, values, np.float32(0)).reshape(-1))
    oracle.assert_bits_equal(libm_expf(total / np.float32(valid.sum())), c["out"], key)
