"""Speeds and accelerations from positions and headings by central differences; displacements.

All arithmetic is float32 in the official order of operations; the functions
take numpy or JAX arrays.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.features.xp import array_namespace, divide, rounded_square, sqrt

_F = np.float32


def central_difference(values: np.ndarray) -> np.ndarray:
    """(v[t+1] - v[t-1]) / 2 along the last axis, NaN at both ends.

    Args:
      values: float32 `(..., num_steps)`.
    Returns:
      float32 `(..., num_steps)`.
    """
    xp = array_namespace(values)
    values = xp.asarray(values, dtype=_F)
    if values.shape[-1] < 3:
        return xp.full(values.shape, np.nan, dtype=_F)
    edge = xp.full(values.shape[:-1] + (1,), np.nan, dtype=_F)
    return xp.concatenate([edge, (values[..., 2:] - values[..., :-2]) / _F(2), edge], axis=-1)


def central_and(valid: np.ndarray) -> np.ndarray:
    """valid[t-1] and valid[t+1] along the last axis, False at both ends.

    Args:
      valid: bool `(..., num_steps)`.
    """
    xp = array_namespace(valid)
    if valid.shape[-1] < 3:
        return xp.zeros(valid.shape, dtype=bool)
    edge = xp.zeros(valid.shape[:-1] + (1,), dtype=bool)
    return xp.concatenate([edge, valid[..., 2:] & valid[..., :-2], edge], axis=-1)


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Maps angles to [-pi, pi) in float32 (floored modulo, as officially).

    The floored modulo by a positive divisor is the truncated one (`fmod`, exact) plus the divisor
    where negative: numpy's `mod` does the same with more work per value (2x slower)."""
    xp = array_namespace(angle)
    turn = _F(2 * np.pi)
    remainder = xp.fmod(angle + _F(np.pi), turn)
    return xp.where(remainder < 0, remainder + turn, remainder) - _F(np.pi)


def linear_speed(x: np.ndarray, y: np.ndarray, z: np.ndarray, seconds_per_step: float) -> np.ndarray:
    """3D speed in m/s, float32 `(..., num_steps)` (NaN at both ends)."""
    dx, dy, dz = central_difference(x), central_difference(y), central_difference(z)
    xp = array_namespace(dx)
    # Each square rounded before the sum, as officially (XLA would fuse one into the addition).
    squares = [rounded_square(d, xp) for d in (dx, dy, dz)]
    return divide(sqrt(squares[0] + squares[1] + squares[2], xp), _F(seconds_per_step))


def kinematic_features(x: Any, y: Any, z: Any, heading: Any, seconds_per_step: float) -> Any:
    """Linear speed, linear acceleration, angular speed, angular acceleration.

    Args:
      x, y, z, heading: float32 `(..., num_steps)`; everything is treated as
        valid (mask afterwards with `kinematic_validity`).
    Returns:
      Four float32 arrays `(..., num_steps)`. Speeds are NaN at the first and
      last step, accelerations at the first two and last two.
    """
    dt = _F(seconds_per_step)
    speed = linear_speed(x, y, z, seconds_per_step)
    acceleration = divide(central_difference(speed), dt)
    # Heading deltas are doubled before wrapping so that the two-step delta of
    # the central difference picks the acute solution, then halved back.
    heading_step = wrap_angle(central_difference(heading) * _F(2)) / _F(2)
    angular_speed = divide(heading_step, dt)
    heading_step2 = wrap_angle(central_difference(heading_step) * _F(2)) / _F(2)
    angular_acceleration = divide(heading_step2, _F(seconds_per_step**2))
    return speed, acceleration, angular_speed, angular_acceleration


def kinematic_validity(valid: np.ndarray) -> Any:
    """Validity of speeds (one central step) and accelerations (two steps).

    Args:
      valid: bool `(..., num_steps)`.
    Returns:
      (speed_valid, acceleration_valid), bool `(..., num_steps)`.
    """
    speed_valid = central_and(valid)
    return speed_valid, central_and(speed_valid)


def displacement_error(x: Any, y: Any, z: Any, ref_x: Any, ref_y: Any, ref_z: Any) -> Any:
    """3D distance between positions and reference positions, float32 (the operands' broadcast shape `(...)`).

    Each square is rounded before the sum, as officially (the norm of the stacked differences).
    """
    xp = array_namespace(x, y, z, ref_x, ref_y, ref_z)
    dx, dy, dz = x - ref_x, y - ref_y, z - ref_z
    return sqrt(rounded_square(dx, xp) + rounded_square(dy, xp) + rounded_square(dz, xp), xp)
