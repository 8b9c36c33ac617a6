"""`waymo_open_dataset.wdl_limited.sim_agents_metrics.trajectory_features`, without TensorFlow.

    linear_speed, linear_accel, angular_speed, angular_accel = trajectory_features.compute_kinematic_features(
        x, y, z, heading, seconds_per_step=0.1)
    speed_valid, accel_valid = trajectory_features.compute_kinematic_validity(valid)

Each function runs the library's own kernel (`wosac_eval.features.kinematics`, the one the metrics
use), in float32 as the official ones compute; the arrays may have any leading axes `(..., num_steps)`.
Arrays in: anything that implements `__array__` or `__dlpack__` (numpy, TensorFlow, torch on the CPU or
a GPU, JAX). Out: numpy arrays answering `.numpy()`, or JAX arrays where the caller passed JAX arrays
(the same kernel under JAX; no TensorFlow anywhere). The official shapes hold for short series too: with
fewer than 3 steps every result has 2 steps, all padding, as the official concatenation makes them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.compat._arrays import Array, ArrayIn, bool_array, check_stackable, float_array, is_jax, out, tf_shape
from wosac_eval.features import kinematics
from wosac_eval.features.xp import array_namespace

_F = np.float32
_PADDED_STEPS = 2  # the official result of fewer than 3 steps: the two pads around no difference


def _steps(t: Array, name: str) -> int:
    if np.ndim(t) < 1:
        raise ValueError(f"{name} must have a steps axis (..., num_steps), got a scalar")
    return t.shape[-1]


def _padded(inner: Array, lead: tuple, pad_value: Any, dtype: Any, xp: Any) -> Array:
    """`inner` `(..., num_steps)` between one pad on each side along the last axis, as the official concatenation."""
    pad = xp.full(lead + (1,), pad_value, dtype=dtype)
    return xp.concatenate([pad, inner, pad], axis=-1)


def central_diff(t: ArrayIn, pad_value: float) -> Array:
    """(t[i+1] - t[i-1]) / 2 along the last axis, `pad_value` at both ends: float32 `(..., num_steps)`.

    Args:
      t: float `(..., num_steps)`.
      pad_value: the value of the first and last step.
    """
    keep = is_jax(t)
    t = float_array(t, "t", keep_jax=keep)
    xp = array_namespace(t)
    lead = t.shape[:-1]
    if _steps(t, "t") < 3:
        inner = xp.zeros(lead + (0,), dtype=_F)
    else:
        inner = kinematics.central_difference(t)[..., 1:-1]
    return out(_padded(inner, lead, _F(pad_value), _F, xp))


def central_logical_and(t: ArrayIn, pad_value: bool) -> Array:
    """t[i-1] and t[i+1] along the last axis, `pad_value` at both ends: bool `(..., num_steps)`.

    Args:
      t: bool `(..., num_steps)`.
      pad_value: the value of the first and last step.
    """
    t = bool_array(t, "t", keep_jax=is_jax(t))
    xp = array_namespace(t)
    lead = t.shape[:-1]
    if _steps(t, "t") < 3:
        inner = xp.zeros(lead + (0,), dtype=bool)
    else:
        inner = kinematics.central_and(t)[..., 1:-1]
    return out(_padded(inner, lead, bool(pad_value), bool, xp))


def compute_displacement_error(
    x: ArrayIn, y: ArrayIn, z: ArrayIn, ref_x: ArrayIn, ref_y: ArrayIn, ref_z: ArrayIn
) -> Array:
    """3D distance between positions and reference positions: float32, the broadcast shape `(...)`.

    x, y, z share one shape, and ref_x, ref_y, ref_z one shape; the two shapes broadcast.

    Raises:
      ValueError: the official messages: "Shapes of all inputs must match" within either triple,
        "Incompatible shapes" between the two.
    """
    keep = is_jax(x, y, z, ref_x, ref_y, ref_z)
    names = ("x", "y", "z", "ref_x", "ref_y", "ref_z")
    values = [float_array(v, n, keep_jax=keep) for v, n in zip((x, y, z, ref_x, ref_y, ref_z), names)]
    check_stackable(values[:3], names[:3])
    check_stackable(values[3:], names[3:])
    try:
        np.broadcast_shapes(np.shape(values[0]), np.shape(values[3]))
    except ValueError:
        stacked = [tuple(np.shape(values[k])) + (3,) for k in (0, 3)]
        raise ValueError(f"Incompatible shapes: {tf_shape(stacked[0])} vs. {tf_shape(stacked[1])}") from None
    return out(kinematics.displacement_error(*values))


def compute_kinematic_features(
    x: ArrayIn, y: ArrayIn, z: ArrayIn, heading: ArrayIn, seconds_per_step: float
) -> tuple[Array, Array, Array, Array]:
    """Speeds and accelerations by central differences (everything counts as valid; mask afterwards).

    Args:
      x, y, z: float `(..., num_steps)`, one shape.
      heading: float `(..., num_steps)`, radians.
      seconds_per_step: the step's duration (0.1 in the challenges).
    Returns:
      (linear_speed, linear_acceleration, angular_speed, angular_acceleration), float32 `(..., num_steps)`:
      speeds NaN at the first and last step, accelerations at the first two and last two.

    Raises:
      ValueError: x, y and z differ in shape (the official message).
    """
    keep = is_jax(x, y, z, heading)
    x, y, z = (float_array(v, n, keep_jax=keep) for v, n in ((x, "x"), (y, "y"), (z, "z")))
    heading = float_array(heading, "heading", keep_jax=keep)
    check_stackable([x, y, z], ("x", "y", "z"))
    features = list(kinematics.kinematic_features(x, y, z, heading, seconds_per_step))
    xp = array_namespace(x, heading)
    # The official shapes of short series: two steps, both NaN (the linear and the angular ones apart).
    for first, source, name in ((0, x, "x"), (2, heading, "heading")):
        if _steps(source, name) < 3:
            features[first : first + 2] = [xp.full(source.shape[:-1] + (_PADDED_STEPS,), np.nan, dtype=_F)] * 2
    return tuple(out(f) for f in features)


def compute_kinematic_validity(valid: ArrayIn) -> tuple[Array, Array]:
    """Validity of the speeds (both neighbours valid) and of the accelerations (applied twice).

    Args:
      valid: bool `(..., num_steps)`.
    Returns:
      (speed_validity, acceleration_validity), bool `(..., num_steps)`.
    """
    valid = bool_array(valid, "valid", keep_jax=is_jax(valid))
    xp = array_namespace(valid)
    if _steps(valid, "valid") < 3:
        none = xp.zeros(valid.shape[:-1] + (_PADDED_STEPS,), dtype=bool)
        return out(none), out(none)
    speed_valid, acceleration_valid = kinematics.kinematic_validity(valid)
    return out(speed_valid), out(acceleration_valid)
