"""`features.float32_sums`: the official `tf.reduce_sum` / `reduce_mean` order, bit for bit.

Against the official arithmetic's answers (`tests/data/oracle_arithmetic`): 1 to 16,385 values (the
packets, the four accumulators, the trailing values, and past 8,192 values the tree of halves), rows
of a 2-D tensor, and the same values behind padding.
"""

from __future__ import annotations

import numpy as np
import pytest

from support import oracle_arithmetic as oracle
from wosac_eval.features.float32_sums import eigen_mean32, eigen_sum32

F = np.float32


@pytest.mark.parametrize("key", oracle.keys("sum"), ids=lambda k: f"{k}-values")
def test_sum_and_mean_are_the_official(key):
    c = oracle.case("sum", key)
    oracle.assert_bits_equal(eigen_sum32(c["in"]), c["out"], f"sum of {key}")
    oracle.assert_bits_equal(eigen_mean32(c["in"]), oracle.case("mean", key)["out"], f"mean of {key}")
    padded = np.concatenate([c["in"], np.full(45, 1e3, F)])
    oracle.assert_bits_equal(eigen_sum32(padded, int(key)), c["out"], f"sum of {key} padded")


@pytest.mark.parametrize("key", oracle.keys("rowsum"), ids=lambda k: f"{k}-values")
def test_row_sums_are_the_official(key):
    c = oracle.case("rowsum", key)
    oracle.assert_bits_equal(eigen_sum32(c["in"]), c["out"], f"row sums of {key}")
    oracle.assert_bits_equal(eigen_mean32(c["in"]), oracle.case("rowmean", key)["out"], f"row means of {key}")


def test_the_cases_tell_the_order_apart():
    """numpy's own float32 sum (pairwise) differs from the official one on some of these cases: they would
    catch an order that is not the official one."""
    differ = [k for k in oracle.keys("sum") if np.sum(oracle.case("sum", k)["in"]) != oracle.case("sum", k)["out"]]
    assert len(differ) >= 3, differ


def test_no_values_is_zero_and_their_mean_nan():
    assert eigen_sum32(np.zeros(0, F)) == 0
    assert np.isnan(eigen_mean32(np.zeros(5, F), 0))
