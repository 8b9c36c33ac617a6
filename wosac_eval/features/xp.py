"""Array-namespace dispatch: one kernel implementation for numpy and JAX.

Kernels call `array_namespace(*arrays)` and use the returned module (`numpy`
or `jax.numpy`) for their arithmetic. JAX is only looked up when it has
already been imported by someone, so the numpy path never imports it.
"""

from __future__ import annotations

import contextlib
import contextvars
import sys
from typing import Any

import numpy as np


def array_namespace(*arrays: Any) -> Any:
    """`jax.numpy` if any argument is a JAX array or tracer, else `numpy`."""
    jax = sys.modules.get("jax")
    if jax is not None:
        for a in arrays:
            if isinstance(a, jax.Array):  # tracers under jit/vmap are jax.Array too
                return jax.numpy
    return np


def is_numpy(xp: Any) -> bool:
    return xp is np


def bitcast(x: Any, dtype: Any, xp: Any) -> Any:
    """Reinterprets the bits of `x` as `dtype` (same item size)."""
    if is_numpy(xp):
        return x.view(dtype)
    from jax import lax

    return lax.bitcast_convert_type(x, dtype)


def errstate(xp: Any, **kwargs: Any) -> Any:
    """`np.errstate` for numpy; JAX has no floating-point warnings to silence."""
    return np.errstate(**kwargs) if is_numpy(xp) else contextlib.nullcontext()


# Set by `float32_precision()`: JAX kernels traced inside it round through float32, not float64.
_FLOAT32_PRECISION = contextvars.ContextVar("wosac_eval_float32_precision", default=False)


@contextlib.contextmanager
def float32_precision() -> Any:
    """JAX kernels traced inside this block use float32 where the exact arithmetic needs float64.

    The exact mode rounds a few steps through float64 (libm `sin`/`cos`, a fused multiply-add, the
    estimators' log-probabilities, padded means); that needs JAX's x64 switch on while tracing,
    which a training loop does not turn on. In float32 precision those steps stay in float32:
    per-step features may differ from the official ones in the last bit, metrics stay within 1e-5.
    numpy code is not affected.
    """
    token = _FLOAT32_PRECISION.set(True)
    try:
        yield
    finally:
        _FLOAT32_PRECISION.reset(token)


def in_float32_precision(xp: Any) -> bool:
    """True for JAX code traced inside `float32_precision()`."""
    return not is_numpy(xp) and _FLOAT32_PRECISION.get()


# Set by `differentiable()`: JAX kernels traced inside it use plain, differentiable operations.
_DIFFERENTIABLE = contextvars.ContextVar("wosac_eval_differentiable", default=False)


@contextlib.contextmanager
def differentiable() -> Any:
    """JAX kernels traced inside this block give real gradients (the soft surrogate, `soft_realism`).

    The exact arithmetic hides some operations from XLA (bit tricks around squares and divisors,
    optimization barriers, Eigen's packet sine), whose gradients are zero or wrong; they only serve
    the last bit. Inside this block they are the plain operations, and a division by zero or the
    square root of zero keeps its value but passes no NaN gradient on. Use it with
    `float32_precision()`; it is read while tracing. numpy code is not affected.
    """
    token = _DIFFERENTIABLE.set(True)
    try:
        yield
    finally:
        _DIFFERENTIABLE.reset(token)


def in_differentiable(xp: Any) -> bool:
    """True for JAX code traced inside `differentiable()`."""
    return not is_numpy(xp) and _DIFFERENTIABLE.get()


def _stop_gradient(v: Any) -> Any:
    from jax import lax

    return lax.stop_gradient(v)


def wide_float(xp: Any) -> Any:
    """The dtype of the steps the official arithmetic rounds through float64, for `xp`.

    numpy: float64. JAX: float64 when x64 is on while tracing, float32 inside
    `float32_precision()`; otherwise a RuntimeError naming both ways out (never a silent switch).
    """
    if is_numpy(xp) or not _FLOAT32_PRECISION.get() and _jax_x64():
        return np.float64
    if _FLOAT32_PRECISION.get():
        return np.float32
    raise RuntimeError(
        "this kernel rounds through float64: trace it under `with jax.enable_x64(True):` "
        "(exact), or inside `wosac_eval.features.xp.float32_precision()` (metrics within 1e-5)"
    )


def _jax_x64() -> bool:
    import jax

    return bool(jax.config.read("jax_enable_x64"))


def through_float64(xp: Any, dtype: Any) -> bool:
    """True where a float32 square root or division is computed in float64 and rounded once.

    XLA's float32 square root and division are not correctly rounded on every device (on an NVIDIA
    H100, 17% and 28% of random operands differ from IEEE in the last bit); its float64 ones are, and
    rounding a float64 quotient or root of float32 operands to float32 gives the correctly rounded
    float32 result (53 >= 2 * 24 + 2 bits). So under JAX with x64 on (the exact mode) they go through
    float64; numpy's float32 ones are correctly rounded, and the float32 mode has no float64.
    """
    return not is_numpy(xp) and np.dtype(dtype) == np.float32 and not _FLOAT32_PRECISION.get() and _jax_x64()


def sqrt(v: Any, xp: Any) -> Any:
    """Square root, correctly rounded also for float32 under JAX with x64 (see `through_float64`)."""
    v = xp.asarray(v)
    if in_differentiable(xp):  # the value of sqrt(0) and sqrt(< 0), without their inf or NaN gradient
        positive = v > 0
        return xp.where(positive, xp.sqrt(xp.where(positive, v, xp.ones_like(v))), _stop_gradient(xp.sqrt(v)))
    if through_float64(xp, v.dtype):
        return xp.sqrt(v.astype(np.float64)).astype(v.dtype)
    return xp.sqrt(v)


def divide(a: Any, b: Any) -> Any:
    """a / b, correctly rounded under JAX too.

    XLA rewrites a division by a broadcast value (a scalar, or a row shared by
    many elements) into a multiplication by its reciprocal, which rounds twice
    and changes the last bit of about a quarter of the results. Under JAX the
    divisor is therefore rebuilt element by element: its bits are OR-ed with
    the dividend's bits AND-ed with an opaque zero, which leaves the value
    unchanged but is no broadcast, also under `vmap` (where the divisor of a
    batched dividend is often unbatched). Kernels use this for every division
    except by powers of two (where both forms are exact).
    """
    xp = array_namespace(a, b)
    if is_numpy(xp):
        return a / b
    from jax import lax

    b = xp.asarray(b)
    if in_differentiable(xp):  # a / 0 or a / NaN keeps its value but passes no NaN gradient on
        plain = (b != 0) & xp.isfinite(b)
        return xp.where(plain, a / xp.where(plain, b, xp.ones_like(b)), _stop_gradient(a / b))
    if through_float64(xp, b.dtype):
        return divide(xp.asarray(a).astype(np.float64), b.astype(np.float64)).astype(b.dtype)
    shape = xp.broadcast_shapes(xp.shape(a), xp.shape(b))
    bits = np.dtype(f"int{8 * b.dtype.itemsize}")
    zero = lax.optimization_barrier(xp.zeros((), bits))
    a_bits = lax.bitcast_convert_type(xp.broadcast_to(a, shape).astype(b.dtype), bits)
    b_bits = lax.bitcast_convert_type(xp.broadcast_to(b, shape), bits) | (a_bits & zero)
    return a / lax.bitcast_convert_type(b_bits, b.dtype)


def rounded_square(a: Any, xp: Any) -> Any:
    """`a * a` rounded to its float type on its own: never fused with the addition it feeds.

    XLA on a GPU (and on a CPU with FMA, without `exact_cpu()`) contracts `a * a + c` into one fused
    multiply-add, which rounds once instead of twice and moves the last bit; the official code rounds
    each square. The square's bits pass through an integer AND that clears the sign bit: a square is
    +0, positive or NaN, so this is the identity (a NaN stays NaN), but the compilers cannot see it, and
    no multiply is left next to the addition. numpy is left as is.
    """
    square = a * a
    if is_numpy(xp) or in_differentiable(xp):
        return square
    from jax import lax

    width = 8 * square.dtype.itemsize
    bits = lax.bitcast_convert_type(square, np.dtype(f"int{width}"))
    sign = (bits >> (width - 1)) << (width - 1)  # shifts, not a constant mask a compiler may read as abs()
    return lax.bitcast_convert_type(bits & ~sign, square.dtype)


def opaque(value: Any, xp: Any) -> Any:
    """`value`, hidden from XLA's algebraic simplifier under JAX.

    XLA folds float expressions such as `(a + c) - c` into `a`, which is
    wrong in floating point (the rounding trick of `float32_math` relies on
    it); an optimization barrier keeps the operations as written.
    """
    if is_numpy(xp) or in_differentiable(xp):
        return value
    from jax import lax

    return lax.optimization_barrier(xp.asarray(value))


def nan_spreading_min(a: Any, axis: int | None = None) -> Any:
    """`a.min(axis)` passing NaN on, as numpy and TensorFlow do (XLA's vectorised CPU reductions drop it)."""
    xp = array_namespace(a)
    return a.min(axis=axis) if is_numpy(xp) else xp.where(xp.isnan(a).any(axis=axis), xp.nan, a.min(axis=axis))


def nan_spreading_max(a: Any, axis: int | None = None) -> Any:
    """`a.max(axis)` passing NaN on (see `nan_spreading_min`)."""
    xp = array_namespace(a)
    return a.max(axis=axis) if is_numpy(xp) else xp.where(xp.isnan(a).any(axis=axis), xp.nan, a.max(axis=axis))
