"""Float32 `log` and `exp` rounded exactly like the official evaluator's CPU kernels.

The official estimators take the log of the histogram counts (`tf.math.log`), a log-sum-exp per
population (`tf.nn.sparse_softmax_cross_entropy_with_logits`) and the exp of each mean
log-likelihood (`tf.exp`). TensorFlow's CPU kernels compute them two ways:

- whole packets of 8 floats by Eigen's polynomial approximations (`plog`, `pexp`: a frexp
  reduction and a (3,3) rational function; a floor reduction by ln 2 in two parts and a degree-6
  polynomial), every multiply and add rounded on its own (the AVX wheels have no fused multiply-add);
- the trailing values of a tensor (or of a reduced row) that fill no packet, and every lone scalar,
  by the C library's `logf` / `expf`: glibc's, which since 2.28 are the table-driven algorithms of
  Arm's optimized-routines (MIT OR Apache-2.0 WITH LLVM-exception; their tables are reproduced below
  from github.com/ARM-software/optimized-routines, math/logf_data.c and math/exp2f_data.c). `logf` is
  not correctly rounded (up to 0.82 units in the last place): between 0.5 and 2, 1.2% of its results
  differ from the correctly rounded ones (5.6% between 0.9 and 1.1, where the sums of exponentials
  lie), so it is evaluated as the library evaluates it, in float64.

TensorFlow's threads run with the CPU's flush-to-zero and denormals-are-zero modes on: a subnormal
operand counts as zero (its `log` is -inf, its `exp` 1) and a subnormal result becomes zero
(`flushed_to_zero` applies both). Both ways agree with TensorFlow 2.13's kernels on every value tried
(`tests/features/float32_explog_test.py` holds cases the official arithmetic gave).

The functions take numpy or JAX arrays; under JAX the float64 steps need x64 while tracing (the exact
mode); inside `xp.float32_precision()` the library functions are the device's own float32 `log`/`exp`
(last-bit differences), and inside `xp.differentiable()` every function is the plain, differentiable one.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.features.float32_sums import PACKET, flushed_to_zero
from wosac_eval.features.xp import (
    array_namespace,
    bitcast,
    divide,
    errstate,
    in_differentiable,
    in_float32_precision,
    is_numpy,
    opaque,
)

_F = np.float32
_D = np.float64

# --- glibc's logf: log(x) = log1p(z/c - 1) + log(c) + k ln2 over 16 subintervals of [0x3f330000, 2x) ---
_LOGF_TABLE = np.array(
    [
        [float.fromhex(invc), float.fromhex(logc)]
        for invc, logc in (
            ("0x1.661ec79f8f3bep+0", "-0x1.57bf7808caadep-2"),
            ("0x1.571ed4aaf883dp+0", "-0x1.2bef0a7c06ddbp-2"),
            ("0x1.49539f0f010bp+0", "-0x1.01eae7f513a67p-2"),
            ("0x1.3c995b0b80385p+0", "-0x1.b31d8a68224e9p-3"),
            ("0x1.30d190c8864a5p+0", "-0x1.6574f0ac07758p-3"),
            ("0x1.25e227b0b8eap+0", "-0x1.1aa2bc79c81p-3"),
            ("0x1.1bb4a4a1a343fp+0", "-0x1.a4e76ce8c0e5ep-4"),
            ("0x1.12358f08ae5bap+0", "-0x1.1973c5a611cccp-4"),
            ("0x1.0953f419900a7p+0", "-0x1.252f438e10c1ep-5"),
            ("0x1p+0", "0x0p+0"),
            ("0x1.e608cfd9a47acp-1", "0x1.aa5aa5df25984p-5"),
            ("0x1.ca4b31f026aap-1", "0x1.c5e53aa362eb4p-4"),
            ("0x1.b2036576afce6p-1", "0x1.526e57720db08p-3"),
            ("0x1.9c2d163a1aa2dp-1", "0x1.bc2860d22477p-3"),
            ("0x1.886e6037841edp-1", "0x1.1058bc8a07ee1p-2"),
            ("0x1.767dcf5534862p-1", "0x1.4043057b6ee09p-2"),
        )
    ],
    dtype=_D,
)
_LOGF_POLY = tuple(float.fromhex(c) for c in ("-0x1.00ea348b88334p-2", "0x1.5575b0be00b6ap-2", "-0x1.ffffef20a4123p-2"))
_LN2 = float.fromhex("0x1.62e42fefa39efp-1")
_LOGF_OFF = 0x3F330000

# --- glibc's expf: exp(x) = 2^(k/32) 2^(r/32), the first from a table, the second a cubic ---
_EXPF_TABLE = np.array(
    [
        0x3FF0000000000000,
        0x3FEFD9B0D3158574,
        0x3FEFB5586CF9890F,
        0x3FEF9301D0125B51,
        0x3FEF72B83C7D517B,
        0x3FEF54873168B9AA,
        0x3FEF387A6E756238,
        0x3FEF1E9DF51FDEE1,
        0x3FEF06FE0A31B715,
        0x3FEEF1A7373AA9CB,
        0x3FEEDEA64C123422,
        0x3FEECE086061892D,
        0x3FEEBFDAD5362A27,
        0x3FEEB42B569D4F82,
        0x3FEEAB07DD485429,
        0x3FEEA47EB03A5585,
        0x3FEEA09E667F3BCD,
        0x3FEE9F75E8EC5F74,
        0x3FEEA11473EB0187,
        0x3FEEA589994CCE13,
        0x3FEEACE5422AA0DB,
        0x3FEEB737B0CDC5E5,
        0x3FEEC49182A3F090,
        0x3FEED503B23E255D,
        0x3FEEE89F995AD3AD,
        0x3FEEFF76F2FB5E47,
        0x3FEF199BDD85529C,
        0x3FEF3720DCEF9069,
        0x3FEF5818DCFBA487,
        0x3FEF7C97337B9B5F,
        0x3FEFA4AFA2A490DA,
        0x3FEFD0765B6E4540,
    ],  # fmt: skip
    dtype=np.uint64,
)
_EXPF_N = 32
_EXPF_POLY = (
    float.fromhex("0x1.c6af84b912394p-5") / _EXPF_N**3,
    float.fromhex("0x1.ebfce50fac4f3p-3") / _EXPF_N**2,
    float.fromhex("0x1.62e42ff0c52d6p-1") / _EXPF_N,
)
_EXPF_INV_LN2_N = float.fromhex("0x1.71547652b82fep+0") * _EXPF_N
_EXPF_SHIFT = float.fromhex("0x1.8p+52")  # adding it rounds to an integer, read from the low bits
_EXPF_OVERFLOW = _F(float.fromhex("0x1.62e42ep6"))
_EXPF_UNDERFLOW = _F(-float.fromhex("0x1.9fe368p6"))


def _plain(xp: Any) -> bool:
    """True where the device's own float32 `log`/`exp` stand in for the C library's (see the module)."""
    return in_differentiable(xp) or in_float32_precision(xp)


def libm_logf(x: Any) -> Any:
    """glibc's `logf` of float32 values (numpy or JAX), bit for bit."""
    xp = array_namespace(x)
    x = flushed_to_zero(xp.asarray(x, _F), xp)
    if _plain(xp):
        return xp.log(x)
    with errstate(xp, over="ignore", under="ignore", invalid="ignore"):
        ix = bitcast(x, np.uint32, xp).astype(np.int64)
        tmp = (ix - _LOGF_OFF) & 0xFFFFFFFF
        i = (tmp >> 19) % 16
        k = (tmp - ((tmp & 0x80000000) << 1)) >> 23  # the arithmetic shift of tmp as an int32
        iz = (ix - (tmp & 0xFF800000)) & 0xFFFFFFFF
        z = bitcast(iz.astype(np.uint32), _F, xp).astype(_D)
        table = xp.asarray(_LOGF_TABLE)
        r = z * table[i, 0] - 1
        y0 = table[i, 1] + k.astype(_D) * _LN2
        r2 = r * r
        y = _LOGF_POLY[1] * r + _LOGF_POLY[2]
        y = _LOGF_POLY[0] * r2 + y
        y = (y * r2 + (y0 + r)).astype(_F)
        # 0 -> -inf, +inf -> +inf, negatives and NaN -> NaN.
        out = xp.where((x > 0) & xp.isfinite(x), y, xp.where(x == 0, _F(-np.inf), xp.where(x > 0, x, _F(np.nan))))
    return xp.where(x == _F(1), _F(0), out)


def libm_expf(x: Any) -> Any:
    """glibc's `expf` of float32 values (numpy or JAX), bit for bit."""
    xp = array_namespace(x)
    x = flushed_to_zero(xp.asarray(x, _F), xp)
    if _plain(xp):
        return xp.exp(x)
    with errstate(xp, over="ignore", under="ignore", invalid="ignore"):
        z = _EXPF_INV_LN2_N * x.astype(_D)
        kd = z + opaque(_D(_EXPF_SHIFT), xp)  # XLA would fold (z + shift) - shift into z
        ki = bitcast(kd, np.uint64, xp)
        kd = kd - _EXPF_SHIFT
        r = z - kd
        t = xp.asarray(_EXPF_TABLE)[(ki % np.uint64(_EXPF_N)).astype(np.int32)] + (ki << np.uint64(47))
        s = bitcast(t, _D, xp)
        p = _EXPF_POLY[0] * r + _EXPF_POLY[1]
        y = _EXPF_POLY[2] * r + 1
        y = flushed_to_zero(((p * (r * r) + y) * s).astype(_F), xp)
    out = xp.where(x > _EXPF_OVERFLOW, _F(np.inf), xp.where(x < _EXPF_UNDERFLOW, _F(0), y))
    return xp.where(xp.isnan(x), x, out)


def _ldexp32(y: Any, m: Any, xp: Any) -> Any:
    """Eigen's `pldexp`: y * 2**m in four float32 products (no overflow on the way), m clamped to +-278."""
    e = xp.clip(m, _F(-278), _F(278)).astype(np.int32)
    b = e >> 2
    c = bitcast((b + 127) << 23, _F, xp)
    out = ((y * c) * c) * c
    return out * bitcast((e - 3 * b + 127) << 23, _F, xp)


def packet_exp32(x: Any) -> Any:
    """Eigen's packet `exp` of float32 values (numpy or JAX)."""
    xp = array_namespace(x)
    x = flushed_to_zero(xp.asarray(x, _F), xp)
    if _plain(xp):
        return xp.exp(x)
    with errstate(xp, over="ignore", under="ignore", invalid="ignore"):
        clamped = xp.minimum(x, _F(88.723))
        m = xp.floor(clamped * _F(1.44269504088896341) + _F(0.5))
        r = m * _F(-0.693359375) + clamped
        r = m * _F(2.12194440e-4) + r
        r2 = r * r
        even = r2 * _F(1.37449637986719608306884765625e-3) + _F(4.166965186595916748046875e-2)
        odd = r2 * _F(8.36894474923610687255859375e-3) + _F(0.16666518151760101318359375)
        even = r2 * even + _F(0.49999988079071044921875)
        y = r * odd + even
        y = r2 * y + (r + _F(1))
        out = flushed_to_zero(xp.maximum(_ldexp32(y, m, xp), x), xp)
    return xp.where(x < _F(-104), _F(0), out)


def packet_log32(x: Any) -> Any:
    """Eigen's packet `log` of float32 values (numpy or JAX)."""
    xp = array_namespace(x)
    x = flushed_to_zero(xp.asarray(x, _F), xp)
    if _plain(xp):
        return xp.log(x)
    with errstate(xp, invalid="ignore", divide="ignore"):
        mantissa, exponent = xp.frexp(x)  # mantissa in [0.5, 1)
        mantissa = mantissa.astype(_F)
        e = exponent.astype(_F)
        # Centre on 1: below sqrt(1/2), double the mantissa and take one from the exponent.
        low = mantissa < _F(0.707106781186547524)
        v = (mantissa - _F(1)) + xp.where(low, mantissa, _F(0))
        e = e - xp.where(low, _F(1), _F(0))
        p = v * _F(0.18256296349849254) + _F(1.0000000190281063)
        p = v * p + _F(1.0000000190281136)
        p = v * p
        q = v * _F(0.049616247954120038) + _F(0.59923249590823520)
        q = v * q + _F(1.4999999999999927)
        q = v * q + _F(1)
        out = e * _F(0.693147180559945309417232121458176568) + divide(p, q)
    out = xp.where(x == _F(np.inf), x, out)
    out = xp.where((x < 0) | xp.isnan(x), _F(np.nan), out)
    return xp.where(x == 0, _F(-np.inf), out)


def tensor_log32(x: Any, count: int | None = None) -> Any:
    """The official `tf.math.log` of a float32 tensor, element by element (numpy or JAX).

    The op runs packets over the flattened tensor and the C library on its trailing values.

    Args:
      x: float32, any shape: the official tensor, or padded along its first axis.
      count: how many leading values of the flattened `x` are the official tensor (the rest
        padding), an int or a traced 0-d integer; None: all of them.
    Returns:
      float32, `x`'s shape.
    """
    return tensors_log32([x], [count])[0]


def tensors_log32(tensors: list, counts: list) -> list:
    """`tensor_log32` of several tensors (`counts`: each one's, as there), each op's values computed
    once over all of them: numpy pays its per-call cost once, not once per tensor."""
    return _by_packets(tensors, counts, packet_log32, libm_logf)


def tensor_exp32(x: Any, count: int | None = None) -> Any:
    """The official `tf.exp` of a float32 tensor, element by element (as `tensor_log32`); a lone
    scalar is the C library's `expf`."""
    return _by_packets([x], [count], packet_exp32, libm_expf)[0]


def row_exp32(x: Any) -> Any:
    """exp of each row as the official reductions of `exp(x)` along the last axis see it: whole
    packets of the row by Eigen's `pexp`, its trailing values by `expf` (numpy or JAX).

    Args:
      x: float32 `(..., num_values)`.
    """
    xp = array_namespace(x)
    x = xp.asarray(x, _F)
    whole = (x.shape[-1] // PACKET) * PACKET
    if is_numpy(xp):  # each function on its own values only
        return np.concatenate([packet_exp32(x[..., :whole]), libm_expf(x[..., whole:])], axis=-1)
    in_packet = xp.arange(x.shape[-1]) < whole
    return xp.where(in_packet, packet_exp32(x), libm_expf(x))


def _by_packets(tensors: list, counts: list, packet: Any, libm: Any) -> list:
    """Each tensor's values by `packet`, but its official tensor's trailing `size % PACKET` by `libm`."""
    xp = array_namespace(*tensors, *counts)
    flats = [xp.asarray(t, _F).reshape(-1) for t in tensors]
    sizes = [f.shape[0] for f in flats]
    official = [size if count is None else count for size, count in zip(sizes, counts)]
    if is_numpy(xp):  # each function on its own values only
        wholes = [(int(n) // PACKET) * PACKET for n in official]
        by_packet = packet(np.concatenate([f[:w] for f, w in zip(flats, wholes)]))
        by_libm = libm(np.concatenate([f[w:] for f, w in zip(flats, wholes)]))
        out, p, q = [], 0, 0
        for tensor, size, w in zip(tensors, sizes, wholes):
            out.append(np.concatenate([by_packet[p : p + w], by_libm[q : q + size - w]]).reshape(np.shape(tensor)))
            p, q = p + w, q + size - w
        return out
    flat = xp.concatenate(flats)
    index = [xp.arange(size) for size in sizes]
    from_libm = xp.concatenate([(i >= (n // PACKET) * PACKET) & (i < n) for i, n in zip(index, official)])
    values = xp.where(from_libm, libm(flat), packet(flat))
    ends = np.cumsum(sizes)
    return [values[end - size : end].reshape(np.shape(t)) for t, end, size in zip(tensors, ends, sizes)]
