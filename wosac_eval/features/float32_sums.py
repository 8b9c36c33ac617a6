"""Float32 sums in the order of the official evaluator's `tf.reduce_sum` (and `reduce_mean`).

TensorFlow reduces a float32 tensor on the CPU with Eigen's inner-most reducer: rows of up to
8 x 1024 values add whole packets of 8 into four accumulators (blocks of 32 values), fold them,
add the remaining whole packets, sum the trailing values one by one and add the horizontal sum
of the accumulator, ((a0+a4)+(a2+a6)) + ((a1+a5)+(a3+a7)); longer rows are split in two at a
packet boundary near the middle and the halves' sums added (a tree). A float32 sum's last bit
depends on that order, so the official means over steps, objects and rollouts are only
reproduced bit for bit by adding in it. `eigen_sum32` does, for numpy and JAX alike.

Padded rows (the JAX backends pad objects to a bucket size) hold the real values first: `count`
says how many, so the order is the official tensor's, not the padded one's. Adding a masked +0
to a partial sum leaves it unchanged, which is what lets one static program follow every count.
TensorFlow's threads run with the CPU's denormals-are-zero mode: a subnormal value is added as zero
(`flushed_to_zero`). The order was checked against TensorFlow 2.13's CPU kernels on random rows of 1 to 70,001 values
(`tests/features/float32_sums_test.py` holds cases the official arithmetic gave).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.features.xp import array_namespace, divide, errstate, is_numpy, opaque

_F = np.float32
PACKET = 8  # AVX float packets: the official TensorFlow wheels are built for AVX.
TINY = _F(np.finfo(_F).tiny)  # the smallest normal float32, 2**-126
_BLOCK = 4 * PACKET  # four accumulators
LEAF = PACKET * 1024  # longer rows are reduced as a tree of halves


def eigen_sum32(values: Any, count: int | None = None) -> Any:
    """Each row's float32 sum in the order of the official `tf.reduce_sum` of that row.

    Each row is summed as a tensor of its own (a full reduction, or `reduce_sum(x, axis=-1)` of
    rows up to `LEAF` long: a longer row of a 2-D tensor would split at other points, which the
    official metrics never meet: they reduce along an axis only rows of bins or of objects).

    Args:
      values: float32 `(..., num_values)` (numpy or JAX).
      count: how many leading values of each row are real (the rest padding), an int or a 0-d
        integer array (traced under JAX); None: all of them.
    Returns:
      float32 `(...)`.
    """
    xp = array_namespace(values, count)
    values = flushed_to_zero(xp.asarray(values, _F), xp)
    if is_numpy(xp):
        if count is not None:
            values = values[..., : int(count)]
        return _tree_numpy(values)
    n = values.shape[-1]
    count = xp.asarray(n if count is None else count, xp.int32)
    return _tree_traced(values, count, n, xp)


def flushed_to_zero(x: Any, xp: Any) -> Any:
    """`x` with its subnormal values as zero of the same sign: TensorFlow's flush-to-zero and
    denormals-are-zero modes, for an operand or a result."""
    return xp.where(xp.abs(x) < TINY, x * _F(0), x)


def eigen_mean32(values: Any, count: int | None = None) -> Any:
    """The official `tf.reduce_mean` of each row: `eigen_sum32` divided by the number of values.

    TensorFlow's mean is the sum divided by the count as a float32 (`count`: as for
    `eigen_sum32`; a row of no values gives NaN, as officially).
    """
    xp = array_namespace(values, count)
    n = values.shape[-1] if count is None else count
    with errstate(xp, invalid="ignore", divide="ignore"):
        # `divide`: under JAX, a quotient no compiler turns into a product by a reciprocal.
        return divide(eigen_sum32(values, count), xp.asarray(n).astype(_F))


def _ceil_div(a: Any, b: Any) -> Any:
    """a / b rounded up, for ints and traced integers."""
    return -(-a // b)


def _tree_numpy(values: np.ndarray) -> np.ndarray:
    n = values.shape[-1]
    if n <= LEAF:
        return packet_sum32(values)
    # Eigen splits at the packet boundary at or after the middle.
    split = PACKET * _ceil_div(_ceil_div(n, 2), PACKET)
    return (_F(0) + _tree_numpy(values[..., :split])) + _tree_numpy(values[..., split:])


def packet_sum32(values: Any) -> Any:
    """One leaf of the official reduction (rows of up to `LEAF` values, all real), numpy or JAX.

    Args:
      values: float32 `(..., num_values)`.
    Returns:
      float32 `(...)`.
    """
    xp = array_namespace(values)
    n = values.shape[-1]
    blocked = (n // _BLOCK) * _BLOCK
    batch = values.shape[:-1]
    if blocked and is_numpy(xp):
        # Each accumulator lane adds its blocks in order: `accumulate` is that running sum by definition.
        blocks = values[..., :blocked].reshape(batch + (blocked // _BLOCK, 4, PACKET))
        lanes = np.add.accumulate(blocks, axis=-3)[..., -1, :, :]
    else:
        lanes = xp.zeros(batch + (4, PACKET), _F)
        for start in range(0, blocked, _BLOCK):
            lanes = lanes + values[..., start : start + _BLOCK].reshape(batch + (4, PACKET))
    acc = ((lanes[..., 0, :] + lanes[..., 1, :]) + lanes[..., 2, :]) + lanes[..., 3, :]
    whole = (n // PACKET) * PACKET
    for start in range(blocked, whole, PACKET):
        acc = acc + values[..., start : start + PACKET]
    tail = xp.zeros(batch, _F)
    for j in range(whole, n):
        tail = tail + values[..., j]
    return tail + _horizontal_sum(acc)


def _horizontal_sum(acc: Any) -> Any:
    """Eigen's `predux` of an AVX packet: the two 128-bit halves added, then ((h0+h2) + (h1+h3))."""
    halves = acc[..., :4] + acc[..., 4:]
    return (halves[..., 0] + halves[..., 2]) + (halves[..., 1] + halves[..., 3])


def _tree_traced(values: Any, count: int, n: int, xp: Any) -> Any:
    """`_tree_numpy` for a traced count: both shapes of the tree computed, the one `count` needs kept."""
    if n <= LEAF:
        return _leaf_traced(values, count, xp)
    split = PACKET * _ceil_div(_ceil_div(count, 2), PACKET)
    left_n = min(n, PACKET * _ceil_div(_ceil_div(n, 2), PACKET))
    left = _tree_traced(values[..., :left_n], xp.minimum(split, count), left_n, xp)
    right_n = n - n // 2
    right = _tree_traced(_shifted(values, split, xp)[..., :right_n], xp.maximum(count - split, 0), right_n, xp)
    whole = _leaf_traced(values, count, xp)
    return xp.where(count > LEAF, (_F(0) + left) + right, whole)


def _shifted(values: Any, start: Any, xp: Any) -> Any:
    """`values[..., start:]`, zero-padded to `values`' length, for a traced `start`."""
    from jax import lax  # JAX is imported only by its callers (the numpy path never reaches here)

    n = values.shape[-1]
    padded = xp.concatenate([values, xp.zeros(values.shape, _F)], axis=-1)
    return lax.dynamic_slice_in_dim(padded, start, n, axis=-1)


def _leaf_traced(values: Any, count: int, xp: Any) -> Any:
    """`packet_sum32` of each row's first `count` values, for a traced `count` (up to `LEAF`)."""
    from jax import lax  # see `_shifted`

    n = values.shape[-1]
    blocked = (count // _BLOCK) * _BLOCK
    whole = (count // PACKET) * PACKET
    size = _ceil_div(n, _BLOCK) * _BLOCK + _BLOCK  # room for the packet and tail windows past the last block
    padded = xp.concatenate([values, xp.zeros(values.shape[:-1] + (size - n,), _F)], axis=-1)
    index = xp.arange(size)
    in_blocks = xp.where(index < blocked, padded, _F(0))
    blocks = xp.moveaxis(in_blocks.reshape(values.shape[:-1] + (size // _BLOCK, 4, PACKET)), -3, 0)

    def add_block(lanes: Any, block: Any) -> Any:
        return lanes + block, None

    # A scan keeps the blocks' order: a reduction would let XLA reassociate the sums.
    lanes, _ = lax.scan(add_block, xp.zeros(blocks.shape[1:], _F), blocks)
    acc = ((lanes[..., 0, :] + lanes[..., 1, :]) + lanes[..., 2, :]) + lanes[..., 3, :]
    packets = lax.dynamic_slice_in_dim(padded, blocked, _BLOCK - PACKET, axis=-1)
    packets = packets.reshape(values.shape[:-1] + (3, PACKET))
    for k in range(3):
        acc = acc + xp.where(blocked + k * PACKET < whole, packets[..., k, :], _F(0))
    trailing = lax.dynamic_slice_in_dim(padded, whole, PACKET - 1, axis=-1)
    tail = xp.zeros(values.shape[:-1], _F)
    for j in range(PACKET - 1):
        tail = tail + xp.where(whole + j < count, trailing[..., j], _F(0))
    return tail + _horizontal_sum(acc)


def split_sum32(values: Any, axis: int = -1) -> Any:
    """Float32 sum along `axis`, as if summed exactly and rounded (nearly always), in any order.

    Each value is split at a power-of-two scale above the row's total magnitude: the high parts
    are multiples of the scale's last place and sum exactly in float32, the low parts are tiny
    and sum with negligible error (Rump's error-free extraction). Used where a float32 sum's
    rounding would otherwise follow the reduction tree (padding, XLA's order): JAX's float32
    precision, instead of a float64 sum.

    Args:
      values: float32 `(..., num_values, ...)` (numpy or JAX), finite values for an accurate result.
    Returns:
      float32, `values` without `axis`.
    """
    xp = array_namespace(values)
    v = xp.asarray(values, _F)
    bound = xp.max(xp.abs(v), axis=axis, keepdims=True) * _F(max(1, v.shape[axis]))
    _, exponent = xp.frexp(bound)  # bound < 2 ** exponent
    scale = opaque(xp.ldexp(xp.ones_like(bound), exponent + 1), xp)  # XLA would fold (v + s) - s
    with errstate(xp, invalid="ignore", over="ignore"):
        high = (v + scale) - scale
        low = v - high
    return high.sum(axis=axis) + low.sum(axis=axis)
