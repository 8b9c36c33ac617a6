"""The official categorical log-probability of each logged value's bin, for many populations at once.

The official histogram estimator (and the Bernoulli one, a two-bin histogram) makes a categorical
distribution of each population's smoothed counts and scores a logged value's bin by the negative
softmax cross-entropy: with `logits = log(counts)` (one `tf.math.log` over the batch's counts) and
`shifted = logits - max(logits)` per row, the value is `shifted[bin] - log(sum(exp(shifted)))`,
every step in float32 with TensorFlow's CPU `log`, `exp` and summation order
(`features.float32_explog`, `features.float32_sums`). A scenario's metrics score about ten such
batches of a few rows each: computed one batch at a time, numpy's per-call cost would dominate, so
`log_probabilities` takes them all and runs each elementwise step once over their union. The
official values do not depend on that grouping: every step is elementwise or per row, and each
batch's packet boundaries follow its own tensor (`BinCounts.num_rows`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from wosac_eval.features.float32_explog import libm_logf, row_exp32, tensors_log32
from wosac_eval.features.float32_sums import eigen_sum32
from wosac_eval.features.xp import array_namespace

_F = np.float32


@dataclasses.dataclass(frozen=True)
class BinCounts:
    """One batch of populations as the official categorical estimate sees it.

    Attributes:
      counts: float32 `(batch, num_bins)`: each population's counts plus the pseudo-count.
      bins: int32 `(batch, num_log_samples)`: the bin of each logged value.
      num_rows: how many leading rows are the official batch (the rest padding), an int or a
        traced 0-d integer; None: all of them.
    """

    counts: Any
    bins: Any
    num_rows: Any = None

    @property
    def num_bins(self) -> int:
        return int(self.counts.shape[1])

    def official_size(self) -> Any:
        """The number of values of the official counts tensor (its `log` op's packets follow it)."""
        return None if self.num_rows is None else self.num_rows * self.num_bins


def log_probabilities(batches: Sequence[BinCounts]) -> list:
    """Each batch's log-probability of its logged values' bins: float32 `(batch, num_log_samples)` each.

    numpy or JAX; the same values as one batch at a time.
    """
    if not batches:
        return []
    xp = array_namespace(*(b.counts for b in batches))
    logits = tensors_log32([b.counts for b in batches], [b.official_size() for b in batches])
    shifted = [row - xp.max(row, axis=1, keepdims=True) for row in logits]
    totals = _row_exp_sums(shifted, xp)
    normalizers = _split(libm_logf(xp.concatenate(totals)), [len(t) for t in totals])
    return [
        -(normalizer[:, None] - xp.take_along_axis(rows, batch.bins, axis=1))
        for batch, rows, normalizer in zip(batches, shifted, normalizers)
    ]


def _row_exp_sums(shifted: list, xp: Any) -> list:
    """sum(exp(row)) of every row, `(batch,)` per batch: the rows of one width in one reduction
    (a row's packets and trailing values depend on its width only)."""
    widths = sorted({rows.shape[1] for rows in shifted})
    totals: list = [None] * len(shifted)
    for width in widths:
        members = [k for k, rows in enumerate(shifted) if rows.shape[1] == width]
        sums = eigen_sum32(row_exp32(xp.concatenate([shifted[k] for k in members])))
        for k, part in zip(members, _split(sums, [shifted[k].shape[0] for k in members])):
            totals[k] = part
    return totals


def _split(values: Any, lengths: Sequence[int]) -> list:
    """`values` cut into consecutive pieces of `lengths`."""
    ends = np.cumsum(lengths)
    return [values[end - length : end] for end, length in zip(ends, lengths)]
