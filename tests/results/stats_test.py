import numpy as np
import pytest
import scipy.stats

from wosac_eval.results import stats


def test_identical_values_give_zero_difference_and_p_one():
    base = np.random.default_rng(3).random((500, 4))
    t = stats.paired_test(base, base.copy(), seed=0, n_boot=500, n_perm=500)
    np.testing.assert_array_equal(t.mean_difference, 0.0)
    np.testing.assert_array_equal(t.ci_low, 0.0)
    np.testing.assert_array_equal(t.ci_high, 0.0)
    np.testing.assert_array_equal(t.p_value, 1.0)
    assert not t.exact_permutation


def test_identical_values_exact_test_gives_p_one():
    base = np.random.default_rng(4).random((6, 2))
    t = stats.paired_test(base, base, n_perm=5000)
    assert t.exact_permutation
    np.testing.assert_array_equal(t.p_value, 1.0)


def test_constant_shift_is_detected_with_degenerate_interval():
    base = np.random.default_rng(5).random((300, 3))
    shift = np.array([0.01, -0.02, 0.0])
    t = stats.paired_test(base, base + shift, seed=1, n_boot=1000, n_perm=999)
    np.testing.assert_allclose(t.mean_difference, shift, atol=1e-12)
    np.testing.assert_allclose(t.ci_low, shift, atol=1e-12)
    np.testing.assert_allclose(t.ci_high, shift, atol=1e-12)
    # A constant non-zero shift is beaten only by the all-keep / all-flip patterns (probability 2/2**300).
    assert t.p_value[0] == pytest.approx(1 / 1000)
    assert t.p_value[1] == pytest.approx(1 / 1000)
    assert t.p_value[2] == 1.0


def test_constant_shift_exact_p_value_is_two_over_all_patterns():
    base = np.random.default_rng(6).random(10)
    t = stats.paired_test(base, base + 0.5, n_perm=5000)
    assert t.exact_permutation
    assert t.p_value[0] == pytest.approx(2 / 2**10)


def test_exact_p_value_by_hand():
    # Signed sums of (1, 2, 3): 6, 4, 2, 0, 0, -2, -4, -6 -> |sum| >= 6 twice in 8, >= 2 in 6 of 8.
    p, exact = stats.permutation_p_value(np.array([1.0, 2.0, 3.0]), np.random.default_rng(0))
    assert exact and p[0] == pytest.approx(2 / 8)
    p, _ = stats.permutation_p_value(np.array([1.0, 3.0, -2.0]), np.random.default_rng(0))
    # Observed sum 2; signed sums of (1, 3, 2) in absolute value: 6, 4, 2, 0, 0, 2, 4, 6 -> 6 of 8 are >= 2.
    assert p[0] == pytest.approx(6 / 8)


def test_exact_p_value_matches_scipy_permutation_test():
    rng = np.random.default_rng(7)
    base = rng.normal(size=11)
    new = base + rng.normal(0.3, 1.0, size=11)
    p, exact = stats.permutation_p_value(new - base, rng, n_perm=5000)
    assert exact
    ref = scipy.stats.permutation_test(
        (new, base),
        lambda x, y: np.mean(x - y),
        permutation_type="samples",
        n_resamples=np.inf,
        alternative="two-sided",
    )
    assert p[0] == pytest.approx(ref.pvalue, rel=1e-9)


def test_monte_carlo_p_value_agrees_with_exact_enumeration():
    rng = np.random.default_rng(8)
    d = rng.normal(0.4, 1.0, size=14)  # 16384 patterns
    exact, is_exact = stats.permutation_p_value(d, rng, n_perm=16384)
    assert is_exact
    approx, is_exact = stats.permutation_p_value(d, np.random.default_rng(9), n_perm=4000)
    assert not is_exact
    # Monte Carlo standard error sqrt(p(1-p)/4000) < 0.008.
    assert abs(approx[0] - exact[0]) < 0.03


def test_p_values_are_uniform_under_the_null():
    # Over many seeds, data with no real difference: the p-value must be (close to) uniform.
    p = np.array(
        [
            stats.paired_test(
                np.zeros(40), np.random.default_rng(seed).standard_t(3, size=40), seed=seed, n_boot=1, n_perm=199
            ).p_value[0]
            for seed in range(400)
        ]
    )
    for level in (0.05, 0.1, 0.25, 0.5, 0.75):
        share = np.mean(p <= level)
        sigma = np.sqrt(level * (1 - level) / p.size)
        assert abs(share - level) < 4 * sigma + 1 / 200, (level, share)  # 1/200: p-value granularity
    assert scipy.stats.kstest(p, "uniform").pvalue > 1e-3


def test_shift_in_noise_is_detected_and_interval_covers_it():
    rng = np.random.default_rng(10)
    base = rng.random(400)
    new = base + 0.01 + rng.normal(0.0, 0.02, 400)
    t = stats.paired_test(base, new, seed=2, n_boot=2000, n_perm=2000)
    assert t.ci_low[0] > 0 and t.ci_low[0] < 0.01 < t.ci_high[0]
    assert t.p_value[0] < 0.001
    # Close to the normal-theory interval mean +- 1.96 sd / sqrt(n).
    d = new - base
    half = 1.96 * d.std(ddof=1) / np.sqrt(d.size)
    assert (t.ci_high[0] - t.ci_low[0]) / 2 == pytest.approx(half, rel=0.15)


def test_bootstrap_interval_coverage_near_nominal():
    covered = 0
    trials = 200
    for seed in range(trials):
        d = np.random.default_rng(seed).exponential(1.0, size=80) - 1.0  # true mean 0, skewed
        low, high = stats.bootstrap_mean_ci(d, np.random.default_rng(10_000 + seed), n_boot=800)
        covered += low[0] <= 0.0 <= high[0]
    assert 0.85 <= covered / trials <= 0.99


def test_results_are_reproducible_for_a_seed_and_vary_across_seeds():
    rng = np.random.default_rng(11)
    base, new = rng.random((200, 2)), rng.random((200, 2))
    a = stats.paired_test(base, new, seed=42, n_boot=300, n_perm=300)
    b = stats.paired_test(base, new, seed=42, n_boot=300, n_perm=300)
    c = stats.paired_test(base, new, seed=43, n_boot=300, n_perm=300)
    np.testing.assert_array_equal(a.ci_low, b.ci_low)
    np.testing.assert_array_equal(a.p_value, b.p_value)
    assert not np.array_equal(a.ci_low, c.ci_low)


def test_metrics_are_tested_independently_of_their_neighbours():
    rng = np.random.default_rng(12)
    base = rng.random((150, 3))
    new = base + [0.0, 0.05, -0.05] + rng.normal(0, 0.01, (150, 3))
    together = stats.paired_test(base, new, seed=0, n_boot=400, n_perm=400)
    alone = stats.paired_test(base[:, 1], new[:, 1], seed=0, n_boot=400, n_perm=400)
    assert together.mean_difference[1] == pytest.approx(alone.mean_difference[0])
    assert together.p_value[1] == alone.p_value[0] == pytest.approx(1 / 401)


def test_small_chunks_give_the_same_kind_of_answer(monkeypatch):
    # Force many chunks (and a partial last one) to exercise the chunked loops.
    monkeypatch.setattr(stats, "_CHUNK_ELEMENTS", 7 * 100)
    rng = np.random.default_rng(13)
    base = rng.random((100, 2))
    shift = np.array([0.02, 0.0])
    t = stats.paired_test(base, base + shift, seed=0, n_boot=50, n_perm=53)
    np.testing.assert_allclose(t.ci_low, shift, atol=1e-12)
    np.testing.assert_allclose(t.ci_high, shift, atol=1e-12)
    np.testing.assert_allclose(t.p_value, [1 / 54, 1.0])


def test_single_scenario_is_accepted_and_empty_is_rejected():
    t = stats.paired_test(np.array([0.2]), np.array([0.3]), n_perm=10)
    assert t.num_pairs == 1 and t.ci_low[0] == pytest.approx(0.1) and t.p_value[0] == 1.0
    with pytest.raises(ValueError, match="at least one scenario"):
        stats.paired_test(np.zeros((0, 2)), np.zeros((0, 2)))
    with pytest.raises(ValueError, match="NaN"):
        stats.paired_test(np.array([0.1, np.nan]), np.array([0.2, 0.3]))
    with pytest.raises(ValueError, match="same shape"):
        stats.paired_test(np.zeros(3), np.zeros(4))


def test_holm_adjustment_by_hand():
    p = np.array([0.01, 0.04, 0.03, 0.5])
    # Sorted 0.01, 0.03, 0.04, 0.5 times 4, 3, 2, 1 -> 0.04, 0.09, 0.08, 0.5 -> running max 0.04, 0.09, 0.09, 0.5.
    np.testing.assert_allclose(stats.holm_adjust(p), [0.04, 0.09, 0.09, 0.5])
    np.testing.assert_allclose(stats.holm_adjust(np.array([0.3, 0.6])), [0.6, 0.6])
    np.testing.assert_allclose(stats.holm_adjust(np.array([0.9, 0.8])), [1.0, 1.0])


def test_exact_enumeration_covers_every_sign_pattern_once():
    # Signed sums of powers of ten are all distinct, and only all-keep / all-flip reach |1111|: if the
    # enumeration repeated or missed patterns the p-value would not be 2/16.
    d = np.array([1.0, 10.0, 100.0, 1000.0])
    p, exact = stats.permutation_p_value(d, np.random.default_rng(0))
    assert exact and p[0] == pytest.approx(2 / 16)


@pytest.mark.parametrize("n_perm", [1, 1000, 4095])
def test_up_to_12_scenarios_are_enumerated_whatever_n_perm(n_perm):
    # compare --n-perm 1000 on 10 scenarios: 1024 patterns, enumerated as the README says, not sampled.
    d = np.random.default_rng(4).normal(0.3, 1.0, size=(10, 2))
    p, exact = stats.permutation_p_value(d, np.random.default_rng(0), n_perm=n_perm)
    reference, reference_exact = stats.permutation_p_value(d, np.random.default_rng(1), n_perm=5000)
    assert exact and reference_exact
    np.testing.assert_array_equal(p, reference)
    p12, exact12 = stats.permutation_p_value(np.ones(12), np.random.default_rng(0), n_perm=n_perm)
    assert exact12 and p12[0] == pytest.approx(2 / 4096)
    _, exact13 = stats.permutation_p_value(np.ones(13), np.random.default_rng(0), n_perm=n_perm)
    assert not exact13
