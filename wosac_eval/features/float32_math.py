"""Float32 elementary functions that round exactly like the official evaluator.

The official metrics run in TensorFlow float32 on CPU. Its `sin`/`cos` are
Eigen's vectorised polynomial approximations (packets of 8 floats, no fused
multiply-add), not the correctly rounded libm values, and they disagree with
numpy's float32 `sin` in the last bit for a few percent of inputs. A last-bit
difference in a box corner can move a distance across a histogram edge or the
collision threshold, so we reproduce the same arithmetic step by step:
Cody-Waite reduction by pi/2 in four float32 pieces, then the minimax
polynomials, each multiply and add rounded separately.

Tensors whose length is not a multiple of the packet size have their last
`n % 8` elements evaluated by the scalar libm routine instead; `packet_tail`
marks those elements for a given official tensor shape.
"""
from __future__ import annotations

import numpy as np

_F = np.float32
_PACKET = 8  # AVX float packets: the official TensorFlow wheels are built for AVX.
_TWO_OVER_PI = _F(0.636619746685028076171875)
_ROUNDING_MAGIC = _F(12582912.0)  # 1.5 * 2**23: adding it rounds to an integer.
_PIO2_PARTS = (_F(-1.5703125), _F(-0.000483989715576171875),
               _F(1.62865035235881805419921875e-07),
               _F(5.5644315544167710640977020375430583953857421875e-11))
_COS_COEFFS = (_F(2.4372266125283204019069671630859375e-05),
               _F(-0.00138865201734006404876708984375),
               _F(0.041666619479656219482421875), _F(-0.5), _F(1.0))
_SIN_COEFFS = (_F(-0.0001959234114083702898469196984621021329076029360294342041015625),
               _F(0.0083326873655616851693794799871284340042620897293090820312500000),
               _F(-0.1666666203982298255503735617821803316473960876464843750000000000))
# Beyond these magnitudes the packet code switches to a slow exact reduction;
# there we fall back to the correctly rounded value.
_HUGE = {True: 25966.0, False: 18838.0}


def _packet_sincos(x: np.ndarray):
    """(sin, cos) of float32 values by Eigen's packet algorithm; one shared reduction."""
    x = np.asarray(x, dtype=_F)
    ax = np.abs(x)
    with np.errstate(invalid="ignore", over="ignore"):
        y_round = ax * _TWO_OVER_PI + _ROUNDING_MAGIC
        quadrant = y_round.view(np.int32)
        y = y_round - _ROUNDING_MAGIC
        r = ax
        for part in _PIO2_PARTS:
            r = y * part + r
        sin_sign = (x.view(np.int32) ^ (quadrant << 30)) & np.int32(-2**31)
        cos_sign = ((quadrant + 1) << 30) & np.int32(-2**31)
        use_first = (quadrant & 1) == 0
        r2 = r * r
        c = _COS_COEFFS[0]
        for coeff in _COS_COEFFS[1:]:
            c = c * r2 + coeff
        s = _SIN_COEFFS[0]
        for coeff in _SIN_COEFFS[1:]:
            s = s * r2 + coeff
        s = (s * r2) * r + r
        sin_out = (np.where(use_first, s, c).view(np.int32) ^ sin_sign).view(_F)
        cos_out = (np.where(use_first, c, s).view(np.int32) ^ cos_sign).view(_F)
    out = []
    for sine, values in ((True, sin_out), (False, cos_out)):
        huge = ax >= _F(_HUGE[sine])
        if np.any(huge):
            exact = (np.sin if sine else np.cos)(x.astype(np.float64)).astype(_F)
            values = np.where(huge & np.isfinite(x), exact, values)
        out.append(values)
    return tuple(out)


def _libm(x: np.ndarray, sine: bool) -> np.ndarray:
    return (np.sin if sine else np.cos)(np.asarray(x, np.float64)).astype(_F)


def packet_tail(shape) -> np.ndarray:
    """Mask of the elements an official op of this shape evaluates with libm.

    Args:
      shape: the full shape of the official op's input tensor.
    Returns:
      bool array of `shape`, True on the trailing `size % 8` elements.
    """
    size = int(np.prod(shape, dtype=np.int64))
    mask = np.zeros(size, dtype=bool)
    mask[size - size % _PACKET:] = True
    return mask.reshape(shape)


def sincos32(x: np.ndarray, libm_mask: np.ndarray | None = None):
    """(sin, cos) of float32 values, rounded as the official evaluator rounds them.

    Args:
      x: float32 array.
      libm_mask: where True, the values are the correctly rounded ones (the
        official op's trailing partial packet, see `packet_tail`).
    """
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


def fma32(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Fused multiply-add a * b + c with a single float32 rounding.

    The product of two float32 values is exact in float64 and so is the sum up
    to one rounding, which is then undone by the final rounding to float32 in
    all but double-rounding corner cases (~2**-29 of inputs).
    """
    return (np.asarray(a, np.float64) * np.asarray(b, np.float64)
            + np.asarray(c, np.float64)).astype(_F)
