"""Tests of speeds and accelerations from central differences."""

import math

import numpy as np

from wosac_eval.features.kinematics import (
    central_and,
    central_difference,
    kinematic_features,
    kinematic_validity,
    linear_speed,
    wrap_angle,
)

F = np.float32
NAN_SPEED = np.array([True] + [False] * 8 + [True])  # 10 steps: speeds are NaN at the ends
NAN_ACCEL = np.array([True, True] + [False] * 6 + [True, True])


def zeros(n=10):
    return np.zeros(n, F)


def test_central_difference_by_hand():
    out = central_difference(np.array([0, 1, 4, 9, 16], F))
    assert out.dtype == F
    np.testing.assert_array_equal(out, np.array([np.nan, 2, 4, 6, np.nan], F))


def test_constant_velocity_straight_line():
    # 0.5 m per step of 0.25 s: 2 m/s exactly (both divisions are by powers of two).
    x = np.arange(10, dtype=F) * F(0.5)
    speed, accel, ang_speed, ang_accel = kinematic_features(x, zeros(), zeros(), zeros(), 0.25)
    for a in (speed, accel, ang_speed, ang_accel):
        assert a.dtype == F and a.shape == (10,)
    np.testing.assert_array_equal(np.isnan(speed), NAN_SPEED)
    np.testing.assert_array_equal(speed[~NAN_SPEED], F(2))
    np.testing.assert_array_equal(np.isnan(accel), NAN_ACCEL)
    np.testing.assert_array_equal(accel[~NAN_ACCEL], F(0))
    np.testing.assert_array_equal(ang_speed[~NAN_SPEED], F(0))
    np.testing.assert_array_equal(ang_accel[~NAN_ACCEL], F(0))


def test_speed_is_three_dimensional():
    # Steps of (3, 4, 12) m: 13 m per step, 1 s per step.
    t = np.arange(6, dtype=F)
    speed = linear_speed(3 * t, 4 * t, 12 * t, 1.0)
    np.testing.assert_array_equal(speed[1:-1], F(13))


def test_speed_with_non_dyadic_step_is_float32_division():
    x = np.arange(5, dtype=F)  # 1 m per 0.1 s
    speed = linear_speed(x, zeros(5), zeros(5), 0.1)
    np.testing.assert_array_equal(speed[1:-1], F(1) / F(0.1))


def test_speed_ignores_direction():
    x = -np.arange(10, dtype=F)  # driving backwards along -x
    y = np.arange(10, dtype=F)
    speed = linear_speed(x, y, zeros(), 1.0)
    np.testing.assert_allclose(speed[1:-1], math.sqrt(2), rtol=2e-7)


def test_constant_acceleration():
    # x = a t^2 / 2 with a = 2 m/s^2 and dt = 0.5 s: x_i = i^2 / 4, speed_i = a t_i = i.
    i = np.arange(10, dtype=F)
    x = i * i / F(4)
    speed, accel, _, _ = kinematic_features(x, zeros(), zeros(), zeros(), 0.5)
    np.testing.assert_array_equal(speed[1:-1], i[1:-1])
    np.testing.assert_array_equal(accel[~NAN_ACCEL], F(2))


def test_deceleration_is_negative():
    i = np.arange(10, dtype=F)
    x = F(20) * i - i * i / F(4)  # speed 40 - i (stays positive), a = -2
    _, accel, _, _ = kinematic_features(x, zeros(), zeros(), zeros(), 0.5)
    np.testing.assert_array_equal(accel[~NAN_ACCEL], F(-2))


def test_heading_wrap_around_gives_small_angular_speed():
    # Turning left at 0.1 rad per 0.1 s step, crossing +pi into -pi.
    unwrapped = 3.0 + 0.1 * np.arange(10)
    heading = ((unwrapped + np.pi) % (2 * np.pi) - np.pi).astype(F)
    assert heading.max() > 3.0 and heading.min() < -3.0  # the wrap really happens
    _, _, ang_speed, ang_accel = kinematic_features(zeros(), zeros(), zeros(), heading, 0.1)
    # float32 headings near pi carry ~2.4e-7 rad of rounding; divided by dt that is ~1e-5.
    np.testing.assert_allclose(ang_speed[~NAN_SPEED], 1.0, atol=2e-5)
    np.testing.assert_allclose(ang_accel[~NAN_ACCEL], 0.0, atol=5e-4)


def test_heading_wrap_around_turning_right():
    unwrapped = -3.0 - 0.2 * np.arange(10)
    heading = ((unwrapped + np.pi) % (2 * np.pi) - np.pi).astype(F)
    _, _, ang_speed, _ = kinematic_features(zeros(), zeros(), zeros(), heading, 0.1)
    np.testing.assert_allclose(ang_speed[~NAN_SPEED], -2.0, atol=2e-5)


def test_angular_acceleration_of_a_tightening_turn():
    # heading = t^2 (rad), dt = 0.5: angular speed 2t, angular acceleration 2.
    t = np.arange(10, dtype=F) * F(0.5)
    heading = wrap_angle(t * t * F(0.1))  # scaled down so that steps stay well under pi/2
    _, _, ang_speed, ang_accel = kinematic_features(zeros(), zeros(), zeros(), heading, 0.5)
    np.testing.assert_allclose(ang_speed[1:-1], 0.2 * t[1:-1], atol=1e-5)
    np.testing.assert_allclose(ang_accel[~NAN_ACCEL], 0.2, atol=1e-4)


def test_wrap_angle_range():
    angles = np.array([0, np.pi, -np.pi, 3 * np.pi, 2 * np.pi, -0.5, 7.0], F)
    wrapped = wrap_angle(angles)
    assert wrapped.dtype == F
    assert np.all(wrapped >= -F(np.pi)) and np.all(wrapped < F(np.pi))
    np.testing.assert_allclose(np.cos(wrapped), np.cos(angles.astype(float)), atol=1e-6)
    np.testing.assert_allclose(wrapped[[0, 5]], [0.0, -0.5])


def test_wrap_angle_is_the_floored_modulo_bit_for_bit():
    """Against numpy's floored `mod` (the official floormod's rule): random angles, multiples of 2 pi
    and their neighbours, zeros of both signs, NaN and infinities."""
    rng = np.random.default_rng(7)
    turns = F(2 * np.pi) * np.arange(-20, 21, dtype=F) - F(np.pi)
    angles = np.concatenate(
        [
            rng.uniform(-40, 40, 200_000),
            turns,
            np.nextafter(turns, F(np.inf)),
            np.nextafter(turns, F(-np.inf)),
            [0.0, -0.0, np.nan, np.inf, -np.inf],
        ]
    ).astype(F)
    with np.errstate(invalid="ignore"):
        expected = np.mod(angles + F(np.pi), F(2 * np.pi)) - F(np.pi)
        np.testing.assert_array_equal(wrap_angle(angles).view(np.int32), expected.view(np.int32))


def test_leading_axes_are_batched():
    x = np.stack([np.arange(10, dtype=F), 2 * np.arange(10, dtype=F)])[None]  # (1, 2, 10)
    speed, accel, _, _ = kinematic_features(x, np.zeros_like(x), np.zeros_like(x), np.zeros_like(x), 1.0)
    assert speed.shape == (1, 2, 10)
    np.testing.assert_array_equal(speed[0, :, 1:-1], [[1] * 8, [2] * 8])
    np.testing.assert_array_equal(accel[0, :, 2:-2], 0)


def test_central_and():
    valid = np.array([1, 1, 1, 0, 1, 1, 1, 1], bool)
    np.testing.assert_array_equal(central_and(valid), [0, 1, 0, 1, 0, 1, 1, 0])


def test_kinematic_validity_masks():
    valid = np.array([1, 1, 1, 0, 1, 1, 1, 1, 1], bool)
    speed_valid, accel_valid = kinematic_validity(valid)
    # Speed at t needs t-1 and t+1; acceleration needs speeds at t-1 and t+1,
    # i.e. positions t-2, t and t+2.
    np.testing.assert_array_equal(speed_valid, [0, 1, 0, 1, 0, 1, 1, 1, 0])
    np.testing.assert_array_equal(accel_valid, [0, 0, 1, 0, 1, 0, 1, 0, 0])


def test_kinematic_validity_all_valid_and_batched():
    valid = np.ones((2, 3, 6), bool)
    valid[1, 2] = False
    speed_valid, accel_valid = kinematic_validity(valid)
    assert speed_valid.shape == accel_valid.shape == (2, 3, 6)
    np.testing.assert_array_equal(speed_valid[0, 0], [0, 1, 1, 1, 1, 0])
    np.testing.assert_array_equal(accel_valid[0, 0], [0, 0, 1, 1, 0, 0])
    assert not speed_valid[1, 2].any() and not accel_valid[1, 2].any()
