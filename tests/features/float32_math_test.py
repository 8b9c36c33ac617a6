"""Tests of the float32 sin/cos/fma that mimic the official evaluator's rounding."""

import numpy as np
import pytest

from wosac_eval.features.float32_math import cos32, packet_tail, sin32

F = np.float32


def ulp_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Number of float32 values between a and b (0 when equal, 1 for neighbours)."""

    def ordered(v):
        bits = np.asarray(v, F).view(np.int32).astype(np.int64)
        # Negative floats count down from -0, so that the integer order follows the float order.
        return np.where(bits < 0, -(bits & 0x7FFFFFFF), bits)

    return np.abs(ordered(a) - ordered(b))


def correctly_rounded(fn, x):
    return fn(np.asarray(x, np.float64)).astype(F)


GRIDS = {
    "dense [-10, 10]": np.linspace(-10, 10, 400_001, dtype=F),
    "up to the slow-reduction threshold": np.linspace(-30_000, 30_000, 120_001, dtype=F),
    "huge": np.linspace(-1e6, 1e6, 20_001, dtype=F),
    # Multiples of pi/2 are where the reduced argument cancels most.
    "multiples of pi/2": (np.arange(-16_000, 16_001) * (np.pi / 2)).astype(F),
}


@pytest.mark.parametrize("grid", GRIDS.values(), ids=GRIDS.keys())
@pytest.mark.parametrize("ours, reference", [(sin32, np.sin), (cos32, np.cos)], ids=["sin", "cos"])
def test_within_two_ulp_of_correctly_rounded(ours, reference, grid):
    result = ours(grid)
    assert result.dtype == F and result.shape == grid.shape
    assert ulp_distance(result, correctly_rounded(reference, grid)).max() <= 2


def test_packet_values_differ_from_libm_somewhere():
    # The point of sin32 is to reproduce Eigen, which is not correctly rounded:
    # if it always matched libm, the packet arithmetic would be dead code.
    x = np.linspace(-10, 10, 10_001, dtype=F)
    assert np.any(sin32(x) != correctly_rounded(np.sin, x))


def test_exact_at_zero():
    assert sin32(F(0)) == F(0)
    assert cos32(F(0)) == F(1)
    zero = sin32(np.array([0.0, -0.0], F))
    assert np.all(zero == 0)


@pytest.mark.parametrize("x", [np.linspace(0, 40_000, 50_001, dtype=F)], ids=["0..40000"])
def test_symmetry(x):
    np.testing.assert_array_equal(sin32(-x), -sin32(x))
    np.testing.assert_array_equal(cos32(-x), cos32(x))


def test_libm_mask_selects_correctly_rounded_values():
    x = np.linspace(-10, 10, 10_001, dtype=F)
    mask = np.zeros(x.shape, bool)
    mask[::3] = True
    out = sin32(x, mask)
    np.testing.assert_array_equal(out[mask], correctly_rounded(np.sin, x[mask]))
    np.testing.assert_array_equal(out[~mask], sin32(x[~mask]))
    out = cos32(x, mask)
    np.testing.assert_array_equal(out[mask], correctly_rounded(np.cos, x[mask]))


# The huge-argument fallback calls np.sin on inf, which warns; the value is what matters.
@pytest.mark.filterwarnings("ignore:invalid value encountered")
def test_nan_and_inf_give_nan():
    out = sin32(np.array([np.nan, np.inf, -np.inf], F))
    assert np.all(np.isnan(out))
    assert np.all(np.isnan(cos32(np.array([np.nan, np.inf], F))))


@pytest.mark.parametrize(
    "shape, tail",
    [
        ((3, 5), 7),  # 15 elements: one packet of 8, then 7 by libm
        ((2, 4), 0),  # exactly one packet
        ((3,), 3),  # shorter than a packet: everything by libm
        ((91,), 3),
        ((4, 2, 3), 0),
        ((5, 1, 3), 7),
    ],
)
def test_packet_tail_marks_trailing_remainder(shape, tail):
    mask = packet_tail(shape)
    assert mask.shape == shape and mask.dtype == bool
    flat = mask.reshape(-1)
    assert flat.sum() == tail
    # The marked elements are exactly the last `tail` in row-major order.
    assert not flat[: flat.size - tail].any()
    assert flat[flat.size - tail :].all()


def test_packet_tail_of_empty_shape():
    assert packet_tail((0, 5)).shape == (0, 5)


def test_split_sum32_rounds_as_the_exact_sum_whatever_the_padding():
    """The float32 precision's padded sums: equal to the float64 sum rounded to float32 (all but
    near-ties), and unchanged by trailing zeros (padding) or the order of the values."""
    from wosac_eval.features.float32_sums import split_sum32

    rng = np.random.default_rng(3)
    values = (rng.lognormal(2, 2, (2000, 128)) * rng.choice([1, -1, 0], (2000, 128), p=[0.8, 0.1, 0.1])).astype(
        np.float32
    )
    want = values.astype(np.float64).sum(axis=1).astype(np.float32)
    got = split_sum32(values)
    assert np.mean(got == want) > 0.999
    np.testing.assert_allclose(got, want, rtol=2**-23, atol=0)
    padded = np.concatenate([values, np.zeros((2000, 72), np.float32)], axis=1)
    np.testing.assert_array_equal(split_sum32(padded), got)
    np.testing.assert_array_equal(split_sum32(values[:, ::-1]), got)
