"""`ops.fma32`: the fused multiply-add of the official box corners, rounded once to float32."""
import numpy as np
import pytest

from wosac_eval.features.ops import fma32

F = np.float32


def test_fma32_rounds_once():
    # a*a = 1 + 2**-11 + 2**-24: the last term is half an ulp of 1, so a
    # separately rounded product drops it (ties to even) and the sum is 0,
    # while the fused operation keeps it.
    a = F(1 + 2.0 ** -12)
    c = F(-(1 + 2.0 ** -11))
    assert (a * a) + c == F(0)
    assert fma32(a, a, c) == F(2.0 ** -24)


def test_fma32_matches_exact_arithmetic_on_representable_results():
    a = np.array([1.5, -2.25, 3.0, 0.0], F)
    b = np.array([2.0, 4.0, -0.5, 7.0], F)
    c = np.array([0.25, 1.0, 1.5, -3.0], F)
    out = fma32(a, b, c)
    assert out.dtype == F
    np.testing.assert_array_equal(out, np.array([3.25, -8.0, 0.0, -3.0], F))


def test_fma32_broadcasts():
    out = fma32(np.array([[1.0], [2.0]], F), np.array([1.0, 2.0, 3.0], F), F(1))
    np.testing.assert_array_equal(out, np.array([[2, 3, 4], [3, 5, 7]], F))


@pytest.mark.xfail(strict=True, reason="documented limitation of fma32: float64 then float32 rounding "
                                       "(double rounding) differs from one rounding in rare cases")
def test_fma32_double_rounding_corner_case():
    # a*a + c = 1 + 2**-11 + 2**-24 + 2**-60 exactly: just above the midpoint
    # between two float32 neighbours, so one rounding goes up. The float64 sum
    # loses the 2**-60 and lands on the midpoint, which then rounds to even (down).
    a = F(1 + 2.0 ** -12)
    c = F(2.0 ** -60)
    assert fma32(a, a, c) == np.nextafter(F(1 + 2.0 ** -11), F(2))
