"""Float32 elementary functions that round exactly like the official evaluator.

The official metrics run in TensorFlow float32 on CPU. Its `sin`/`cos` are
Eigen's vectorised polynomial approximations (packets of 8 floats, no fused
multiply-add), not the correctly rounded libm values, and they disagree with
numpy's float32 `sin` in the last bit for a few percent of inputs. A last-bit
difference in a box corner can move a distance across a histogram edge or the
collision threshold, so we reproduce the same arithmetic step by step:
Cody-Waite reduction by pi/2 in four float32 pieces, then the minimax
polynomials, each multiply and add rounded separately.

The functions take numpy or JAX arrays. Under JAX the libm path (like
`ops.fma32`, the fused multiply-add of the box corners) rounds through float64
when x64 is on while tracing (exact); inside `xp.float32_precision()` it stays
in float32 (last-bit differences).

Tensors whose length is not a multiple of the packet size have their last
`n % 8` elements evaluated by the scalar libm routine instead; `packet_tail`
marks those elements for a given official tensor shape.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.features import ops
from wosac_eval.features.float32_sums import PACKET
from wosac_eval.features.xp import array_namespace, errstate, in_differentiable, is_numpy, wide_float

_F = np.float32
_TWO_OVER_PI = _F(0.636619746685028076171875)
_ROUNDING_MAGIC = _F(12582912.0)  # 1.5 * 2**23: adding it rounds to an integer.
_PIO2_PARTS = (
    _F(-1.5703125),
    _F(-0.000483989715576171875),
    _F(1.62865035235881805419921875e-07),
    _F(5.5644315544167710640977020375430583953857421875e-11),
)
_COS_COEFFS = (
    _F(2.4372266125283204019069671630859375e-05),
    _F(-0.00138865201734006404876708984375),
    _F(0.041666619479656219482421875),
    _F(-0.5),
    _F(1.0),
)
_SIN_COEFFS = (
    _F(-0.0001959234114083702898469196984621021329076029360294342041015625),
    _F(0.0083326873655616851693794799871284340042620897293090820312500000),
    _F(-0.1666666203982298255503735617821803316473960876464843750000000000),
)
# Beyond these magnitudes the packet code switches to a slow exact reduction;
# there we fall back to the correctly rounded value.
_HUGE = {True: 25966.0, False: 18838.0}
HUGE_SIN, HUGE_COS = _F(_HUGE[True]), _F(_HUGE[False])


def packet_sincos(x: Any) -> Any:
    """(sin, cos) of float32 values by Eigen's packet algorithm, one shared reduction (an `ops` kernel).

    The quadrant is the integer the rounding trick leaves in y; its low two bits decide which
    polynomial each result takes and the signs (what Eigen reads from y's bit pattern).
    """
    ax = ops.absolute(x)
    magic = ops.opaque(_ROUNDING_MAGIC, x)  # XLA would fold (v + magic) - magic into v
    y = (ax * _TWO_OVER_PI + magic) - magic
    quadrant = ops.int32(y)
    r = ax
    for part in _PIO2_PARTS:
        r = y * part + r
    r2 = r * r
    c = _COS_COEFFS[0]
    for coeff in _COS_COEFFS[1:]:
        c = c * r2 + coeff
    s = _SIN_COEFFS[0]
    for coeff in _SIN_COEFFS[1:]:
        s = s * r2 + coeff
    s = (s * r2) * r + r
    use_sin_polynomial = (quadrant & 1) == 0
    sin_negative = ops.signbit(x) != ((quadrant & 2) != 0)
    cos_negative = ((quadrant + 1) & 2) != 0
    sin_out = ops.where(use_sin_polynomial, s, c)
    cos_out = ops.where(use_sin_polynomial, c, s)
    return ops.where(sin_negative, -sin_out, sin_out), ops.where(cos_negative, -cos_out, cos_out)


def _packet_sincos(x: Any) -> Any:
    """`packet_sincos` of an array, with the correctly rounded value where the packet code takes its
    slow exact reduction (huge finite values)."""
    xp = array_namespace(x)
    x = xp.asarray(x, dtype=_F)
    ax = xp.abs(x)
    with errstate(xp, invalid="ignore", over="ignore"):
        sin_out, cos_out = packet_sincos(x)
    out = []
    for sine, values in ((True, sin_out), (False, cos_out)):
        huge = ax >= _F(_HUGE[sine])
        # numpy skips the fallback when no value needs it; traced code cannot branch on data.
        if not is_numpy(xp) or np.any(huge):
            values = xp.where(huge & xp.isfinite(x), _libm(x, sine), values)
        out.append(values)
    return tuple(out)


def _libm(x: Any, sine: bool) -> Any:
    xp = array_namespace(x)
    return (xp.sin if sine else xp.cos)(xp.asarray(x, wide_float(xp))).astype(_F)


def packet_tail(shape: Any) -> np.ndarray:
    """Mask of the elements an official op of this shape evaluates with libm.

    Args:
      shape: the full shape of the official op's input tensor.
    Returns:
      bool array of `shape`, True on the trailing `size % 8` elements.
    """
    size = int(np.prod(shape, dtype=np.int64))
    mask = np.zeros(size, dtype=bool)
    mask[size - size % PACKET :] = True
    return mask.reshape(shape)


def sincos32(x: np.ndarray, libm_mask: np.ndarray | None = None) -> Any:
    """(sin, cos) of float32 values, rounded as the official evaluator rounds them.

    Args:
      x: float32 array.
      libm_mask: where True, the values are the correctly rounded ones (the
        official op's trailing partial packet, see `packet_tail`).
    """
    xp = array_namespace(x, libm_mask)
    if in_differentiable(xp):  # the packet algorithm's quadrant rounding has a wrong gradient
        x = xp.asarray(x, dtype=_F)
        return xp.sin(x), xp.cos(x)
    if not is_numpy(xp):
        x = xp.asarray(x, dtype=_F)
        sin, cos = _packet_sincos(x)
        if libm_mask is not None:
            # Traced code selects instead of assigning in place.
            mask = xp.broadcast_to(libm_mask, x.shape)
            sin, cos = xp.where(mask, _libm(x, True), sin), xp.where(mask, _libm(x, False), cos)
        return sin, cos
    x = np.asarray(x, dtype=_F)
    sin, cos = _packet_sincos(x)
    if libm_mask is not None and x.ndim:
        where = np.nonzero(np.broadcast_to(libm_mask, x.shape))
        if where[0].size:
            sin[where] = _libm(x[where], True)
            cos[where] = _libm(x[where], False)
    elif libm_mask is not None and np.any(libm_mask):
        sin, cos = _libm(x, True), _libm(x, False)
    return sin, cos


def sin32(x: np.ndarray, libm_mask: np.ndarray | None = None) -> np.ndarray:
    """`sin` of float32 values, rounded as the official evaluator rounds them (see `sincos32`)."""
    return sincos32(x, libm_mask)[0]


def cos32(x: np.ndarray, libm_mask: np.ndarray | None = None) -> np.ndarray:
    """`cos` counterpart of `sin32`."""
    return sincos32(x, libm_mask)[1]
