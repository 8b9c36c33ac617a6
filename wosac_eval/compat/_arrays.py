"""Arrays in and out of the compat modules.

In: whatever a caller of the official functions passes, numpy arrays,
TensorFlow tensors, torch tensors (on the CPU, or on a GPU through
`__dlpack__`), JAX arrays, lists: anything that implements `__array__` or
`__dlpack__` (`host_array`), read as float32 or bool as the official functions
compute (`float_array`, `bool_array`).

Out: numpy arrays that also answer `.numpy()`, as the official tensors do.
Client programs of the official modules often end a computation with
`tensor.numpy()` (e.g. `getattr(features, name).numpy()`); the compat modules
hand out `CompatArray`s, plain numpy arrays in every other respect, so that such
code runs unchanged. (A single element, `array[i]`, is a numpy scalar, which has
no `.numpy()`.) Functions with a JAX path (`trajectory_features`) hand JAX
arrays back to callers that passed JAX arrays (`is_jax`).
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

_F = np.float32
# What the functions take: anything implementing `__array__` or `__dlpack__` (or a list), and what those with a
# JAX path return: a numpy array (`CompatArray`) or a JAX array.
ArrayIn = Any
Array = Any


class CompatArray(np.ndarray):
    """A numpy array with the `.numpy()` of a TensorFlow eager tensor."""

    def numpy(self) -> np.ndarray:
        """A copy as a plain `numpy.ndarray`."""
        return np.array(self.view(np.ndarray), copy=True)


def compat_array(value: Any, dtype: Any = None) -> CompatArray:
    """`value` (array-like) as a `CompatArray`, of `dtype` when given."""
    return np.asarray(value, dtype=dtype).view(CompatArray)


def is_jax(*values: Any) -> bool:
    """True if any value is a JAX array (JAX is only looked up when someone imported it)."""
    jax = sys.modules.get("jax")
    return jax is not None and any(isinstance(v, jax.Array) for v in values)


def host_array(value: ArrayIn, name: str) -> np.ndarray:
    """Any array in as a numpy array in host memory (no copy where none is needed).

    `__array__` first (numpy, TensorFlow, torch and JAX on the CPU, lists), then
    `__dlpack__` asked for a CPU copy (a torch tensor on a GPU, whose `__array__`
    refuses).

    Raises:
      ValueError: neither way reads it (naming `name` and why, e.g. a torch tensor that
        requires grad: detach it first).
    """
    if isinstance(value, np.ndarray):
        return value
    refusals = []
    if hasattr(value, "__array__") or not hasattr(value, "__dlpack__"):
        try:
            return np.asarray(value)
        # What array libraries raise when their array cannot be read here (a device, a gradient).
        except (TypeError, RuntimeError, ValueError, BufferError) as error:
            refusals.append(f"__array__: {error}")
    if hasattr(value, "__dlpack__"):
        try:
            return _from_dlpack(value)
        except (TypeError, RuntimeError, ValueError, BufferError) as error:
            refusals.append(f"__dlpack__: {error}")
    raise ValueError(f"{name}: cannot read a {type(value).__name__} as an array ({'; '.join(refusals)})")


def _from_dlpack(value: Any) -> np.ndarray:
    """`np.from_dlpack` asking the producer for a copy on the CPU (numpy >= 2.1; older numpy reads CPU memory)."""
    try:
        return np.from_dlpack(value, device="cpu")
    except TypeError as error:
        if "device" not in str(error):
            raise
        return np.from_dlpack(value)  # numpy < 2.1: no device argument


def float_array(value: ArrayIn, name: str, keep_jax: bool = False) -> Array:
    """`value` as float32 (numpy, or JAX where `keep_jax` and it is a JAX array).

    Raises:
      ValueError: it is not an array of real numbers (naming `name`).
    """
    if keep_jax and is_jax(value):
        import jax.numpy as jnp  # only reached when the caller already imported JAX

        return jnp.asarray(value, dtype=_F)
    array = host_array(value, name)
    if array.dtype.kind not in "biuf":
        raise ValueError(f"{name} must be an array of real numbers, got dtype {array.dtype}")
    return array.astype(_F, copy=False)


def bool_array(value: ArrayIn, name: str, keep_jax: bool = False) -> Array:
    """`value` as a bool array (numpy, or JAX where `keep_jax` and it is a JAX array).

    Raises:
      ValueError: it is not boolean (naming `name`): the official functions refuse numbers there too.
    """
    if keep_jax and is_jax(value):
        if value.dtype != bool:
            raise ValueError(f"{name} must be a boolean array, got dtype {value.dtype}")
        return value
    array = host_array(value, name)
    if array.dtype != bool:
        raise ValueError(f"{name} must be a boolean array, got dtype {array.dtype}")
    return array


def tf_shape(shape: Any) -> str:
    """A shape as TensorFlow's messages write it: `[4,5]`."""
    return "[" + ",".join(str(n) for n in shape) + "]"


def check_stackable(arrays: Any, names: Any = None) -> None:
    """ValueError with the official message (TensorFlow's stack) unless all arrays have one shape.

    `names` (optional) are added after the official text, naming the arguments at fault.
    """
    first = np.shape(arrays[0])
    for i, a in enumerate(arrays[1:], 1):
        if np.shape(a) != first:
            named = f" ({names[0]} and {names[i]})" if names else ""
            raise ValueError(
                f"Shapes of all inputs must match: values[0].shape = {tf_shape(first)} != "
                f"values[{i}].shape = {tf_shape(np.shape(a))}{named}"
            )


def out(value: Array, dtype: Any = None) -> Array:
    """A result as the compat modules hand it out: a `CompatArray`, or a JAX array as it is."""
    return value if is_jax(value) else compat_array(value, dtype)
