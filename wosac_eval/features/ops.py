"""The elementwise operations of kernels written once for numpy, JAX and numba.

A per-element kernel (a segment distance, a box distance, a following gap) is
written with Python's arithmetic operators and the functions of this module,
called as `ops.where(...)`, `ops.sqrt(...)`. Called with numpy or JAX arrays,
each function dispatches on its arguments (`xp.array_namespace`), so the kernel
runs vectorised. `features.compiled.compiled(kernel)` makes the same source a
numba function of scalars: it swaps this module for `features.compiled`'s
scalar twin, with the same names and the same results bit for bit (NaN and the
sign of zero included), and the compiled search loops call it per element.

Rules for a kernel, so that all three work: float32 values and constants
(`np.float32(...)`, never a bare Python float, which numba would widen to
float64), no `with` blocks (callers silence numpy's warnings), no methods on
values (`ops.float32(v)`, not `v.astype(...)`), other kernels called by their
bare name, and `ops.where` for every choice.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.features import xp as _xp
from wosac_eval.features.xp import array_namespace

_F = np.float32


def where(condition: Any, a: Any, b: Any) -> Any:
    """`a` where `condition` is True, else `b` (both are evaluated)."""
    return array_namespace(condition, a, b).where(condition, a, b)


def sqrt(v: Any) -> Any:
    """Square root, correctly rounded (`xp.sqrt`: also where XLA's float32 one is not)."""
    return _xp.sqrt(v, array_namespace(v))


def absolute(v: Any) -> Any:
    return array_namespace(v).abs(v)


def minimum(a: Any, b: Any) -> Any:
    """Elementwise minimum passing NaN on (numpy's and JAX's `minimum`)."""
    return array_namespace(a, b).minimum(a, b)


def maximum(a: Any, b: Any) -> Any:
    """Elementwise maximum passing NaN on."""
    return array_namespace(a, b).maximum(a, b)


def clip(v: Any, low: Any, high: Any) -> Any:
    return array_namespace(v, low, high).clip(v, low, high)


def sign(v: Any) -> Any:
    """-1, 0 or 1 (0 for both zeros), NaN for NaN: numpy's `sign`."""
    return array_namespace(v).sign(v)


def isnan(v: Any) -> Any:
    return array_namespace(v).isnan(v)


def isfinite(v: Any) -> Any:
    return array_namespace(v).isfinite(v)


def divide(a: Any, b: Any) -> Any:
    """a / b, correctly rounded (`xp.divide`: also under XLA's rewrites)."""
    return _xp.divide(a, b)


def fma32(a: Any, b: Any, c: Any) -> Any:
    """Fused multiply-add a * b + c with a single float32 rounding.

    The product of two float32 values is exact in float64 and so is the sum up
    to one rounding, which is then undone by the final rounding to float32 in
    all but double-rounding corner cases (~2**-29 of inputs).
    """
    xp = array_namespace(a, b, c)
    wide = _xp.wide_float(xp)  # float32 in JAX's float32 precision: then two roundings, not one
    return (xp.asarray(a, wide) * xp.asarray(b, wide) + xp.asarray(c, wide)).astype(_F)


def float32(v: Any) -> Any:
    """`v` as float32."""
    return array_namespace(v).asarray(v, _F)


def int32(v: Any) -> Any:
    """`v` as int32 (truncating floats)."""
    return array_namespace(v).asarray(v, np.int32)


def signbit(v: Any) -> Any:
    """True where the sign bit is set (negative numbers, -0.0, NaN with the bit)."""
    return array_namespace(v).signbit(v)


def opaque(v: Any, like: Any) -> Any:
    """`v`, hidden from XLA's algebraic simplifier when `like` is a JAX array (`xp.opaque`); numpy
    and numba leave it as is. `like` gives the namespace, since `v` is often a constant."""
    return _xp.opaque(v, array_namespace(like))


def pick4(i: Any, v0: Any, v1: Any, v2: Any, v3: Any) -> Any:
    """`(v0, v1, v2, v3)[i]` elementwise, for `i` in 0..3."""
    return where(i == 0, v0, where(i == 1, v1, where(i == 2, v2, v3)))
