"""Paired statistics for comparing two scoring runs scenario by scenario.

Both tests work on paired differences `d = new - base`, shape
`(num_scenarios, num_metrics)`: one row per scenario scored in both runs, one
column per metric. Every metric is resampled with the same scenario draws, so
the intervals of related metrics (a bucket and its likelihoods) stay coherent.

- Bootstrap: resample scenarios with replacement, `(num_resamples, num_scenarios)`
  index draws, and take the 2.5 / 97.5 percentiles of the resampled means.
- Permutation: the paired (sign-flip) test. Under "no difference" each
  scenario's difference is as likely to have either sign, so flipping signs at
  random gives the null distribution of the mean difference. Two-sided.

Draws are made in chunks of rows so that 44k scenarios x 10k resamples never
materialises more than a few million numbers at once; a resample's mean is a
row of `counts @ d / n` (bootstrap) or `signs @ d / n` (permutation), one
matrix product per chunk. Everything is seeded through `numpy.random.Generator`
so that a given (input, seed) gives the same answer on every machine.
"""

from __future__ import annotations

import dataclasses

import numpy as np

# Elements of one chunk of draws (rows x scenarios): bounds memory at ~32 MB of
# int64 however many scenarios there are.
_CHUNK_ELEMENTS = 4_000_000
# Up to this many scenarios, all 2**n sign patterns fit in memory ((65536, 16) at most) and the
# permutation test is exact when n_perm asks for at least that many draws.
_MAX_EXACT_SCENARIOS = 16
# Up to this many scenarios (4096 patterns) the test is exact whatever n_perm asks for: enumerating
# is then cheaper than the default 5000 draws, and a smaller n_perm must not turn it into sampling.
_ALWAYS_EXACT_SCENARIOS = 12
# Differences this close to the observed statistic count as ties: means of the
# same numbers summed in different orders differ by rounding only.
_TIE_RELATIVE_TOLERANCE = 1e-9


@dataclasses.dataclass(frozen=True)
class PairedSettings:
    """How every paired comparison of two runs is tested and judged: the same settings for the comparison
    per metric (`compare.compare_results`), per stratum (`stratify`) and per object (`per_object_compare`).

    Attributes:
      alpha: the significance level of the verdicts; the intervals are (1 - alpha) intervals.
      adjust: "none" or "holm": verdicts from the raw or the Holm-adjusted p-values (the per-object
        comparison ranks its strata by the raw ones, and lists the adjusted ones beside).
      seed: seeds the bootstrap and the permutation draws.
      n_boot: bootstrap resamples.
      n_perm: random sign flips of the permutation test.
    """

    alpha: float = 0.05
    adjust: str = "none"
    seed: int = 0
    n_boot: int = 5000
    n_perm: int = 5000

    def __post_init__(self) -> None:
        if self.adjust not in ("none", "holm"):
            raise ValueError(f"adjust must be 'none' or 'holm', got {self.adjust!r}")
        if not 0 < self.alpha < 1:
            raise ValueError(f"alpha must be between 0 and 1, got {self.alpha}")
        if self.n_boot < 1 or self.n_perm < 1:
            raise ValueError("n_boot and n_perm must be at least 1")

    def test(self, base: np.ndarray, new: np.ndarray) -> PairedTest:
        """`paired_test` of `new - base` with these settings (intervals at 1 - alpha)."""
        return paired_test(base, new, seed=self.seed, n_boot=self.n_boot, n_perm=self.n_perm, confidence=1 - self.alpha)


@dataclasses.dataclass(frozen=True)
class PairedTest:
    """Result of the paired tests for each metric, arrays of shape `(num_metrics,)`."""

    mean_difference: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    p_value: np.ndarray
    num_pairs: int
    exact_permutation: bool


def _as_matrix(differences: np.ndarray) -> np.ndarray:
    d = np.asarray(differences, dtype=np.float64)
    if d.ndim == 1:
        d = d[:, None]
    if d.ndim != 2:
        raise ValueError(f"paired differences must have shape (num_scenarios, num_metrics), got {d.shape}")
    if d.shape[0] == 0:
        raise ValueError("paired tests need at least one scenario present in both results")
    if not np.all(np.isfinite(d)):
        raise ValueError("paired differences contain NaN or infinity")
    return d


def _chunk_rows(num_scenarios: int) -> int:
    return max(1, _CHUNK_ELEMENTS // max(1, num_scenarios))


def bootstrap_mean_ci(
    differences: np.ndarray,
    rng: np.random.Generator,
    n_boot: int = 5000,
    confidence: float = 0.95,
) -> tuple[np.ndarray, np.ndarray]:
    """Percentile bootstrap interval of the mean paired difference.

    Args:
      differences: `(num_scenarios, num_metrics)` or `(num_scenarios,)` new - base.
      rng: seeded generator; consumed in a fixed order so results are reproducible.
      n_boot: number of resamples.
      confidence: two-sided coverage, e.g. 0.95.

    Returns:
      `(low, high)`, each `(num_metrics,)`.
    """
    d = _as_matrix(differences)
    n, m = d.shape
    means = np.empty((n_boot, m))
    rows = _chunk_rows(n)
    counts = np.empty((min(rows, n_boot), n))  # (chunk, num_scenarios) times each scenario was drawn
    for start in range(0, n_boot, rows):
        c = min(rows, n_boot - start)
        idx = rng.integers(0, n, size=(c, n), dtype=np.int32 if n < 2**31 else np.int64)
        for r in range(c):  # one row at a time: a 44k-bin histogram stays in cache
            counts[r] = np.bincount(idx[r], minlength=n)
        means[start : start + c] = counts[:c] @ d / n
    tail = (1.0 - confidence) / 2.0 * 100.0
    low, high = np.percentile(means, [tail, 100.0 - tail], axis=0)
    return low, high


def permutation_p_value(
    differences: np.ndarray,
    rng: np.random.Generator,
    n_perm: int = 5000,
) -> tuple[np.ndarray, bool]:
    """Two-sided paired sign-flip permutation p-value of "mean difference is 0".

    With up to 12 scenarios, or up to 16 when `2**num_scenarios <= n_perm`, every
    sign pattern is enumerated and the p-value is exact; otherwise `n_perm` random patterns are drawn and the
    p-value is `(1 + #{|perm mean| >= |observed|}) / (1 + n_perm)`, which never
    reports 0 and keeps the test valid (p-values are not anti-conservative).

    Args:
      differences: `(num_scenarios, num_metrics)` or `(num_scenarios,)` new - base.
      rng: seeded generator (unused when the test is exact).
      n_perm: number of random sign patterns.

    Returns:
      `(p_values, exact)`: `(num_metrics,)` p-values and whether they are exact.
    """
    d = _as_matrix(differences)
    n, m = d.shape
    observed = np.abs(d.mean(axis=0))
    threshold = observed - _TIE_RELATIVE_TOLERANCE * np.maximum(np.abs(d).mean(axis=0), 1e-300)
    if n <= _ALWAYS_EXACT_SCENARIOS or (n <= _MAX_EXACT_SCENARIOS and 2**n <= n_perm):
        patterns = np.arange(2**n)[:, None] >> np.arange(n)[None, :] & 1  # (2**n, n) bits
        signs = 1.0 - 2.0 * patterns
        extreme = (np.abs(signs @ d / n) >= threshold).sum(axis=0)
        return extreme / 2**n, True
    extreme = np.zeros(m, dtype=np.int64)
    total = d.sum(axis=0)
    rows = _chunk_rows(n)
    bits = np.empty((min(rows, n_perm), n))  # (chunk, num_scenarios) 1 where the sign is kept
    for start in range(0, n_perm, rows):
        c = min(rows, n_perm - start)
        raw = np.frombuffer(rng.bytes((c * n + 7) // 8), dtype=np.uint8)
        bits[:c] = np.unpackbits(raw, count=c * n).reshape(c, n)
        # sum(s_i d_i) with s_i = 2 b_i - 1 is 2 sum(b_i d_i) - sum(d_i).
        permuted = (2.0 * (bits[:c] @ d) - total) / n
        extreme += (np.abs(permuted) >= threshold).sum(axis=0)
    return (1.0 + extreme) / (1.0 + n_perm), False


def paired_test(
    base: np.ndarray,
    new: np.ndarray,
    seed: int = 0,
    n_boot: int = 5000,
    n_perm: int = 5000,
    confidence: float = 0.95,
) -> PairedTest:
    """Mean difference, bootstrap interval and permutation p-value of `new - base`.

    Args:
      base, new: `(num_scenarios, num_metrics)` per-scenario values, rows paired
        (the same scenario in both).
      seed: seeds the bootstrap and the permutation draws (independent streams).
    """
    base = np.asarray(base, dtype=np.float64)
    new = np.asarray(new, dtype=np.float64)
    if base.shape != new.shape:
        raise ValueError(f"paired values must have the same shape, got {base.shape} and {new.shape}")
    d = _as_matrix(new - base)
    boot_rng, perm_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    low, high = bootstrap_mean_ci(d, boot_rng, n_boot=n_boot, confidence=confidence)
    p, exact = permutation_p_value(d, perm_rng, n_perm=n_perm)
    return PairedTest(
        mean_difference=d.mean(axis=0),
        ci_low=low,
        ci_high=high,
        p_value=p,
        num_pairs=d.shape[0],
        exact_permutation=exact,
    )


def holm_adjust(p_values: np.ndarray) -> np.ndarray:
    """Holm-Bonferroni adjusted p-values (family-wise error control), same shape as input."""
    p = np.asarray(p_values, dtype=np.float64)
    m = p.size
    order = np.argsort(p, kind="stable")
    stepped = np.maximum.accumulate((m - np.arange(m)) * p[order])
    adjusted = np.empty(m)
    adjusted[order] = np.minimum(stepped, 1.0)
    return adjusted
