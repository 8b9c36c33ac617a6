"""Tests of the histogram, Bernoulli and kernel-density log-likelihoods against hand counts."""

import math
import re

import numpy as np
import pytest

from wosac_eval.estimators import likelihoods
from wosac_eval.protos import sim_agents_metrics_pb2

F = np.float32
nan = float("nan")


# --- Edges and bins ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "lo, hi, bins",
    [(-12.0, 12.0, 11), (0.0, 25.0, 10), (-0.628, 0.628, 11), (-3.14, 3.14, 11), (-5.0, 40.0, 10), (-20.0, 40.0, 10)],
)
def test_edges_are_float32_start_plus_i_step(lo, hi, bins):
    edges = likelihoods.histogram_edges(lo, hi, bins)
    assert edges.dtype == F and edges.shape == (bins + 1,)
    start, stop = F(lo), F(hi)
    step = (stop - start) / F(bins)
    expected = [start] + [start + F(i) * step for i in range(1, bins)] + [stop]
    np.testing.assert_array_equal(edges, np.array(expected, F))


def test_edges_of_minus_12_to_12_are_not_symmetric():
    edges = likelihoods.histogram_edges(-12, 12, 11)
    assert edges[0] == -12 and edges[-1] == 12
    # The middle bin is [-1.0909090, 1.0909100): float32 rounding of
    # -12 + i * (24 / 11) is not mirrored on the positive side.
    assert edges[5] == F(-1.0909090042114258) and edges[6] == F(1.0909099578857422)
    assert -edges[5] != edges[6]
    # So 12/11 in float32 (1.0909091) still falls in the middle bin, and its
    # negation falls in the bin below: a float64 linspace would say otherwise.
    b = likelihoods.histogram_bins(np.array([F(12 / 11), -F(12 / 11)]), edges)
    np.testing.assert_array_equal(b, [5, 4])
    linspace64 = np.linspace(-12, 12, 12)
    assert np.searchsorted(linspace64, float(F(12 / 11)), side="right") - 1 == 6


def test_bins_closed_on_the_left_last_bin_closed():
    edges = likelihoods.histogram_edges(0, 10, 10)
    values = np.array([0.0, 0.999, 1.0, 5.5, 9.0, 9.999, 10.0], F)
    np.testing.assert_array_equal(likelihoods.histogram_bins(values, edges), [0, 0, 1, 5, 9, 9, 9])


def _first_edge_at_or_above(values, edges):
    """The bins by a binary search over the edges (what `histogram_bins` computes by comparisons)."""
    clipped = np.clip(values.astype(F), edges[0], edges[-1])
    index = np.searchsorted(edges, clipped, side="right") - 1
    return np.clip(np.where(np.isnan(clipped), len(edges) - 2, index), 0, len(edges) - 2)


@pytest.mark.parametrize("config", ["2023", "2024", "2025", "scenario_gen_2025"])
def test_bins_equal_a_binary_search_over_the_edges_at_every_edge(config):
    """Every histogram of the official configs: each edge, the floats next to it, random values, the
    extremes; the bins counted from the interior edges equal those of a binary search, and so do
    `histogram_counts` of rows of them, weighted or not."""
    from wosac_eval.metrics.config import load_config

    rng = np.random.default_rng(0)
    loaded = load_config(config)
    histograms = [
        getattr(loaded, f.name).histogram
        for f in loaded.DESCRIPTOR.fields
        if getattr(getattr(loaded, f.name), "WhichOneof", lambda _: None)("estimator") == "histogram"
    ]
    assert histograms
    for h in histograms:
        edges = likelihoods.histogram_edges(h.min_val, h.max_val, h.num_bins)
        near = [np.nextafter(edges, F(np.inf)), np.nextafter(edges, F(-np.inf))]
        values = np.concatenate(
            [
                edges,
                *near,
                rng.uniform(h.min_val - 1, h.max_val + 1, 10_000),
                [np.inf, -np.inf, np.nan, 1e30, -1e30, 0.0, -0.0],
            ]
        ).astype(F)
        expected = _first_edge_at_or_above(values, edges)
        np.testing.assert_array_equal(likelihoods.histogram_bins(values, edges), expected)
        bincount = lambda bins, w=None: np.bincount(bins, w, minlength=h.num_bins)  # noqa: E731
        np.testing.assert_array_equal(likelihoods.histogram_counts(values[None], edges), [bincount(expected)])
        # Rows of 23 (the extremes are last), weighted or not.
        n = len(values) // 23 * 23
        rows, row_bins = values[-n:].reshape(-1, 23), expected[-n:].reshape(-1, 23)
        weights = rng.integers(0, 2, rows.shape).astype(float)
        np.testing.assert_array_equal(likelihoods.histogram_counts(rows, edges), [bincount(b) for b in row_bins])
        np.testing.assert_array_equal(
            likelihoods.histogram_counts(rows, edges, weights), [bincount(b, w) for b, w in zip(row_bins, weights)]
        )


def test_bins_clip_out_of_range_values():
    edges = likelihoods.histogram_edges(0, 10, 10)
    values = np.array([-5.0, -1e30, 11.0, 1e30, np.inf, -np.inf], F)
    np.testing.assert_array_equal(likelihoods.histogram_bins(values, edges), [0, 0, 9, 9, 9, 0])


def test_nan_goes_to_the_last_bin():
    edges = likelihoods.histogram_edges(-5, 40, 10)
    np.testing.assert_array_equal(likelihoods.histogram_bins(np.array([nan, 0.0], F), edges), [9, 1])


# --- Histogram log-likelihood ----------------------------------------------------------------------


def test_histogram_against_hand_counts():
    # 4 bins of width 1 on [0, 4]; 10 clips into the last bin.
    sim = np.array([[0.5, 0.5, 1.5, 3.9, 10.0]])
    log = np.array([[0.2, 2.5, 3.0, -7.0]])
    out = likelihoods.histogram_log_likelihood(0, 4, 4, 0.1, log, sim)
    assert out.shape == (1, 4) and out.dtype == F
    counts = np.array([2.1, 1.1, 0.1, 2.1])
    total = counts.sum()
    expected = np.log(counts[[0, 2, 3, 0]] / total)
    np.testing.assert_allclose(out[0], expected, rtol=1e-6)


def test_histogram_rows_are_independent_populations():
    sim = np.array([[0.5, 0.5], [1.5, 1.5]])
    log = np.array([[0.5], [0.5]])
    out = likelihoods.histogram_log_likelihood(0, 2, 2, 1.0, log, sim)
    np.testing.assert_allclose(out[:, 0], np.log([3 / 4, 1 / 4]), rtol=1e-6)


def test_histogram_nan_samples_count_in_the_last_bin():
    sim = np.array([[nan, nan, 0.5]])
    log = np.array([[nan, 0.5]])
    out = likelihoods.histogram_log_likelihood(0, 2, 2, 0.5, log, sim)
    # Counts [1, 2] + 0.5: the NaN log sample scores the last bin.
    np.testing.assert_allclose(out[0], np.log([2.5 / 4, 1.5 / 4]), rtol=1e-6)


def test_pseudocount_keeps_empty_bins_finite():
    out = likelihoods.histogram_log_likelihood(0, 10, 10, 0.1, np.array([[9.5]]), np.full((1, 32), 0.5))
    np.testing.assert_allclose(out, [[math.log(0.1 / (32 + 10 * 0.1))]], rtol=1e-6)


# --- Bernoulli --------------------------------------------------------------------------------------


def test_bernoulli_against_hand_counts():
    sim = np.array([[True, True, False, False, False]])
    log = np.array([[True, False]])
    p = 0.001
    out = likelihoods.bernoulli_log_likelihood(p, log, sim)
    total = 5 + 2 * p
    np.testing.assert_allclose(out[0], np.log([(2 + p) / total, (3 + p) / total]), rtol=1e-6)


def test_bernoulli_all_agree():
    out = likelihoods.bernoulli_log_likelihood(0.001, np.array([[False]]), np.zeros((1, 32), bool))
    # log(32.001 / 32.002), as the official float32 arithmetic reaches it: the log of its float32 sum of
    # exponentials, 1 + 3.1e-5 rounded to float32, is off by up to 2**-24 (the exact bits: the oracle cases).
    np.testing.assert_allclose(out, [[math.log(32.001 / 32.002)]], rtol=0, atol=2**-24)


# --- Layouts --------------------------------------------------------------------------------------


def histogram_config(independent: bool, aggregate: bool = False):
    config = likelihoods.FeatureConfig()
    config.histogram.min_val, config.histogram.max_val = 0.0, 2.0
    config.histogram.num_bins = 2
    config.histogram.additive_smoothing_pseudocount = 1.0
    config.independent_timesteps = independent
    config.aggregate_objects = aggregate
    return config


# (rollouts=2, objects=2, steps=3); bin 0 is [0, 1), bin 1 is [1, 2].
SIM = np.array(
    [
        [[0.5, 0.5, 0.5], [1.5, 0.5, 1.5]],
        [[0.5, 0.5, 0.5], [1.5, 0.5, 0.5]],
    ]
)
LOG = np.array([[0.5, 1.5, 0.5], [1.5, 1.5, 0.5]])


def test_independent_timesteps_pool_rollouts_and_steps_per_object():
    out = likelihoods.timeseries_log_likelihood(histogram_config(True), LOG, SIM)
    assert out.shape == (2, 3) and out.dtype == F
    # Object 0: six samples in bin 0 -> counts [7, 1] / 8.
    # Object 1: three in each bin -> [4, 4] / 8.
    np.testing.assert_allclose(out, np.log([[7 / 8, 1 / 8, 7 / 8], [1 / 2, 1 / 2, 1 / 2]]), rtol=1e-6)


def test_dependent_timesteps_one_population_per_object_and_step():
    out = likelihoods.timeseries_log_likelihood(histogram_config(False), LOG, SIM)
    # Object 0: each step [3, 1] / 4. Object 1: step 0 [1, 3], step 1 [3, 1], step 2 [2, 2] (over 4).
    np.testing.assert_allclose(out, np.log([[3 / 4, 1 / 4, 3 / 4], [3 / 4, 1 / 4, 2 / 4]]), rtol=1e-6)


def test_aggregate_objects_independent_timesteps_pools_everything():
    out = likelihoods.timeseries_log_likelihood(histogram_config(True, aggregate=True), LOG, SIM)
    # All 12 samples: 9 in bin 0, 3 in bin 1 -> [10, 4] / 14.
    np.testing.assert_allclose(out, np.log([[10 / 14, 4 / 14, 10 / 14], [4 / 14, 4 / 14, 10 / 14]]), rtol=1e-6)


def test_aggregate_objects_dependent_timesteps_pools_objects_per_step():
    out = likelihoods.timeseries_log_likelihood(histogram_config(False, aggregate=True), LOG, SIM)
    # Step 0: [2, 2] + 1 -> [3, 3] / 6; step 1: [4, 0] -> [5, 1] / 6; step 2: [3, 1] -> [4, 2] / 6.
    np.testing.assert_allclose(out, np.log([[3 / 6, 1 / 6, 4 / 6], [3 / 6, 1 / 6, 4 / 6]]), rtol=1e-6)


def test_timeseries_shape_mismatch():
    with pytest.raises(ValueError, match="log values .* must have shape"):
        likelihoods.timeseries_log_likelihood(histogram_config(True), LOG[:, :2], SIM)


def test_scenario_level_bernoulli_per_object_over_rollouts():
    config = likelihoods.FeatureConfig()
    config.bernoulli.SetInParent()  # default pseudo-count 0.001
    sim = np.array([[True, False], [True, False], [False, False]])  # (rollouts=3, objects=2)
    log = np.array([True, True])
    out = likelihoods.scenario_level_log_likelihood(config, log, sim)
    assert out.shape == (2,)
    p = 0.001
    np.testing.assert_allclose(out, np.log([(2 + p) / (3 + 2 * p), p / (3 + 2 * p)]), rtol=1e-5)


def test_config_without_estimator():
    with pytest.raises(ValueError, match="no estimator"):
        likelihoods.timeseries_log_likelihood(likelihoods.FeatureConfig(), LOG, SIM)


# --- Kernel density -------------------------------------------------------------------------------


def test_kernel_density_dirac_scores_zero():
    out = likelihoods.kernel_density_log_likelihood(0.5, np.array([[3.0]]), np.array([[3.0]]))
    assert out.dtype == F
    assert out[0, 0] == 0.0


def test_kernel_density_by_hand():
    out = likelihoods.kernel_density_log_likelihood(1.0, np.array([[0.0, 1.0]]), np.array([[0.0, 2.0]]))
    expected = [math.log((1 + math.exp(-2)) / 2), math.log(math.exp(-0.5))]
    np.testing.assert_allclose(out[0], expected, rtol=1e-6)


def test_kernel_density_far_samples_do_not_underflow():
    out = likelihoods.kernel_density_log_likelihood(1.0, np.array([[0.0]]), np.array([[100.0, 100.0]]))
    np.testing.assert_allclose(out, [[-5000.0]], rtol=1e-7)


def test_kernel_density_bandwidth_must_be_positive():
    with pytest.raises(ValueError, match="bandwidth"):
        likelihoods.kernel_density_log_likelihood(0.0, np.zeros((1, 1)), np.zeros((1, 1)))


def test_kernel_density_via_config():
    config = likelihoods.FeatureConfig()
    config.kernel_density.bandwidth = 2.0
    config.independent_timesteps = True
    log = np.array([[0.0]])
    sim = np.array([[[2.0]], [[-2.0]]])  # two rollouts, one object, one step
    out = likelihoods.timeseries_log_likelihood(config, log, sim)
    np.testing.assert_allclose(out, [[-0.5]], rtol=1e-6)


@pytest.mark.parametrize("log_shape, sim_shape", [((3, 5), (4, 32)), ((3,), (3, 32)), ((3, 5), (3, 32, 2))])
def test_mismatched_batches_are_refused_naming_both_shapes(log_shape, sim_shape):
    rng = np.random.default_rng(0)
    log, sim = rng.normal(size=log_shape).astype(np.float32), rng.normal(size=sim_shape).astype(np.float32)
    for estimate in (
        lambda: likelihoods.histogram_log_likelihood(-1, 1, 4, 0.1, log, sim),
        lambda: likelihoods.kernel_density_log_likelihood(0.5, log, sim),
        lambda: likelihoods.bernoulli_log_likelihood(0.001, log > 0, sim > 0),
    ):
        with pytest.raises(
            ValueError,
            match=rf"log samples {re.escape(str(log_shape))} and simulated samples "
            rf"{re.escape(str(sim_shape))}",
        ):
            estimate()


def test_timeseries_and_scenario_level_shapes_are_checked():
    config = sim_agents_metrics_pb2.SimAgentMetricsConfig.FeatureConfig()
    config.histogram.min_val, config.histogram.max_val, config.histogram.num_bins = 0, 1, 4
    with pytest.raises(ValueError, match=r"log values \(4, 80\) must have shape \(3, 80\).*\(32, 3, 80\)"):
        likelihoods.timeseries_log_likelihood(config, np.zeros((4, 80), np.float32), np.zeros((32, 3, 80), np.float32))
    with pytest.raises(ValueError, match=r"simulated values must be \(num_rollouts, num_objects, num_steps\)"):
        likelihoods.timeseries_log_likelihood(config, np.zeros((3, 80), np.float32), np.zeros((3, 80), np.float32))
    with pytest.raises(ValueError, match=r"log values \(4,\) must be \(num_objects,\)"):
        likelihoods.scenario_level_log_likelihood(config, np.zeros(4, bool), np.zeros((32, 3), bool))
