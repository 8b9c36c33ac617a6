"""Tests of distance to the nearest object, collisions and time to collision on hand-built scenes."""

import math

import numpy as np
import pytest

from wosac_eval.features import following, interaction
from wosac_eval.features.float32_math import cos32, sin32
from wosac_eval.features.search_strategy import TimeToCollisionInputs

F = np.float32


def scene(*boxes, steps=1, valid=None):
    """Arrays `(num_objects, steps)` for boxes (x, y, length, width, heading) held still."""
    values = np.array(boxes, np.float64)
    arrays = [np.repeat(values[:, k : k + 1], steps, axis=1).astype(F) for k in range(5)]
    x, y, length, width, heading = arrays
    if valid is None:
        valid = np.ones(x.shape, bool)
    return x, y, length, width, heading, np.asarray(valid, bool)


def nearest(*boxes, num_evaluated=None, steps=1, valid=None):
    x, y, length, width, heading, valid = scene(*boxes, steps=steps, valid=valid)
    n = len(boxes) if num_evaluated is None else num_evaluated
    return interaction.distance_to_nearest_object(x, y, length, width, cos32(heading), sin32(heading), valid, n)


# Car-sized boxes, 4 m x 2 m: rounding radius 0.7 * min(4, 2) / 2 = 0.7 m, core 2.6 m x 0.6 m.
CAR = (4.0, 2.0, 0.0)
TOL = 2e-6  # a few float32 roundings of values ~10 m


def test_face_to_face_gap():
    # Facing ends: the rounded corners do not matter, the gap is 10 - 2 - 2.
    d = nearest((0, 0, *CAR), (10, 0, *CAR))
    assert d.shape == (2, 1) and d.dtype == F
    np.testing.assert_allclose(d, 6.0, atol=TOL)


def test_side_by_side_gap():
    np.testing.assert_allclose(nearest((0, 0, *CAR), (0, 5, *CAR)), 3.0, atol=TOL)


def test_corner_to_corner_uses_rounded_corners():
    # Sharp corners (2, 1) and (8, 9) would be 10 m apart. The rounded shapes
    # are the cores (half sizes 1.3 x 0.3) grown by 0.7 m: core corners
    # (1.3, 0.3) and (8.7, 9.7), so the distance is |(7.4, 9.4)| - 2 * 0.7.
    d = nearest((0, 0, *CAR), (10, 10, *CAR))
    np.testing.assert_allclose(d, math.hypot(7.4, 9.4) - 1.4, atol=TOL)
    assert d[0, 0] > 10.0


def test_rounding_radius_follows_each_box_size():
    # A 10 m x 6 m box (radius 2.1, core 5.8 x 1.8) and a 2 m square
    # (radius 0.7, core 0.6 x 0.6), diagonal: core corners (2.9, 0.9) and (19.7, 19.7).
    d = nearest((0, 0, 10, 6, 0), (20, 20, 2, 2, 0))
    np.testing.assert_allclose(d, math.hypot(19.7 - 2.9, 19.7 - 0.9) - 2.1 - 0.7, atol=5e-6)


def test_rotated_vertex_towards_face():
    # Two 2 m squares (radius 0.7, core 0.6 m square); the second turned 45
    # degrees at x = 5: its core's left vertex is at 5 - 0.3 * sqrt(2), the
    # first core's right face at 0.3.
    d = nearest((0, 0, 2, 2, 0), (5, 0, 2, 2, math.pi / 4))
    np.testing.assert_allclose(d, 5 - 0.3 * math.sqrt(2) - 0.3 - 1.4, atol=TOL)


@pytest.mark.parametrize(
    "gap, distance, expected_collision",
    [
        (0.5, 0.5, False),
        (-0.5, -0.5, True),
        # 3 m deep lengthwise: sideways is shorter, 0.6 m between the cores plus both radii.
        (-3.0, -2.0, True),
    ],
)
def test_collisions_are_negative_distances(gap, distance, expected_collision):
    d = nearest((0, 0, *CAR), (4 + gap, 0, *CAR))
    np.testing.assert_allclose(d, distance, atol=TOL)
    collided = d < F(interaction.COLLISION_DISTANCE_THRESHOLD)
    assert np.all(collided == expected_collision)


def test_touching_is_zero():
    np.testing.assert_allclose(nearest((0, 0, *CAR), (4, 0, *CAR)), 0.0, atol=TOL)


def test_alone_is_extremely_large():
    d = nearest((0, 0, *CAR))
    np.testing.assert_array_equal(d, interaction.EXTREMELY_LARGE_DISTANCE)


def test_self_is_never_the_nearest():
    # Each box overlaps itself completely; that must not count.
    d = nearest((0, 0, *CAR), (30, 0, *CAR))
    np.testing.assert_allclose(d, 26.0, atol=1e-5)


def test_invalid_objects_are_ignored():
    valid = [[True, True], [False, True], [True, True]]
    d = nearest((0, 0, *CAR), (5, 0, *CAR), (20, 0, *CAR), steps=2, valid=valid)
    # Step 0: the close neighbour is invalid, the far one counts.
    np.testing.assert_allclose(d[0], [16.0, 1.0], atol=1e-5)
    # The invalid object itself gets the sentinel at its invalid step.
    assert d[1, 0] == interaction.EXTREMELY_LARGE_DISTANCE
    np.testing.assert_allclose(d[1, 1], 1.0, atol=TOL)


def test_only_evaluated_objects_are_scored_against_everyone():
    # Object 0 is evaluated; objects 1 and 2 are other sim agents.
    d = nearest((0, 0, *CAR), (30, 0, *CAR), (0, 4, *CAR), num_evaluated=1)
    assert d.shape == (1, 1)
    np.testing.assert_allclose(d, 2.0, atol=TOL)


def test_batched_rollouts_and_steps():
    x, y, length, width, heading, valid = scene((0, 0, *CAR), (10, 0, *CAR), steps=3)
    x = np.stack([x, x + np.array([[0], [5]], F)])  # rollout 1 moves the second box 5 m further
    shape = x.shape
    b = lambda a: np.broadcast_to(a, shape)
    d = interaction.distance_to_nearest_object(
        x, b(y), b(length), b(width), b(cos32(heading)), b(sin32(heading)), b(valid), 2
    )
    assert d.shape == (2, 2, 3)
    np.testing.assert_allclose(d[0], 6.0, atol=TOL)
    np.testing.assert_allclose(d[1], 11.0, atol=5e-6)


# --- Time to collision --------------------------------------------------------------------------

DT = 0.5
STEPS = 5
INNER = slice(1, 4)  # speeds need both neighbours
T = np.arange(STEPS, dtype=F)


def time_to_collision(x, y, length, width, heading, valid, **options):
    """`following.time_to_collision` of these arrays (`options`: the other `TimeToCollisionInputs` fields)."""
    boxes = {"x": x, "y": y, "length": length, "width": width, "heading": heading, "valid": valid}
    return following.time_to_collision(TimeToCollisionInputs(**boxes, **options))


def ttc(*tracks, num_evaluated=1, valid=None):
    """Tracks are (x(t), y(t), length, width, heading) with x, y arrays over STEPS."""
    x = np.stack([np.broadcast_to(np.asarray(tr[0], F), (STEPS,)) for tr in tracks])
    y = np.stack([np.broadcast_to(np.asarray(tr[1], F), (STEPS,)) for tr in tracks])
    length, width, heading = (np.stack([np.full(STEPS, tr[k], F) for tr in tracks]) for k in (2, 3, 4))
    if valid is None:
        valid = np.ones(x.shape, bool)
    return time_to_collision(
        x,
        y,
        length,
        width,
        heading,
        np.asarray(valid, bool),
        num_evaluated=num_evaluated,
        seconds_per_step=DT,
        steps=INNER,
    )


FOLLOWER = (F(5) * T, 0.0, 4.0, 2.0, 0.0)  # 10 m/s along +x


def test_follower_behind_slower_leader():
    # Leader at 5 m/s starting 12 m ahead: bumper gap 12 + 2.5 t - 5 t - 2 - 2,
    # closing speed 5 m/s.
    leader = (F(12) + F(2.5) * T, 0.0, 4.0, 2.0, 0.0)
    out = ttc(FOLLOWER, leader)
    assert out.shape == (1, 3) and out.dtype == F
    gap = np.array([5.5, 3.0, 0.5], F)
    np.testing.assert_array_equal(out[0], gap / F(5))


def test_capped_at_five_seconds():
    leader = (F(40) + F(2.5) * T, 0.0, 4.0, 2.0, 0.0)  # gap 33.5 m at step 1: 6.7 s
    np.testing.assert_array_equal(ttc(FOLLOWER, leader), following.MAXIMUM_TIME_TO_COLLISION)


def test_faster_leader():
    leader = (F(12) + F(7.5) * T, 0.0, 4.0, 2.0, 0.0)
    np.testing.assert_array_equal(ttc(FOLLOWER, leader), 5.0)


def test_leader_beside_is_not_in_the_path():
    leader = (F(12) + F(2.5) * T, 5.0, 4.0, 2.0, 0.0)  # lateral gap 5 - 1 - 1 = 3 m
    np.testing.assert_array_equal(ttc(FOLLOWER, leader), 5.0)


def test_opposite_heading_is_not_followed():
    oncoming = (F(12), 0.0, 4.0, 2.0, math.pi)  # standing still, facing us
    np.testing.assert_array_equal(ttc(FOLLOWER, oncoming), 5.0)


def test_object_behind_is_not_followed():
    behind = (F(-20) + F(2.5) * T, 0.0, 4.0, 2.0, 0.0)
    np.testing.assert_array_equal(ttc(FOLLOWER, behind), 5.0)


def test_invalid_leader_is_ignored():
    leader = (F(12) + F(2.5) * T, 0.0, 4.0, 2.0, 0.0)
    valid = np.ones((2, STEPS), bool)
    valid[1, 2] = False
    out = ttc(FOLLOWER, leader, valid=valid)
    np.testing.assert_array_equal(out[0], [F(5.5) / F(5), 5.0, F(0.5) / F(5)])


def test_nearest_leader_decides_even_if_a_farther_one_is_slower():
    fast_near = (F(12) + F(7.5) * T, 0.0, 4.0, 2.0, 0.0)
    parked_far = (F(60), 0.0, 4.0, 2.0, 0.0)
    np.testing.assert_array_equal(ttc(FOLLOWER, fast_near, parked_far), 5.0)
    slow_near = (F(12) + F(2.5) * T, 0.0, 4.0, 2.0, 0.0)
    np.testing.assert_array_equal(ttc(FOLLOWER, parked_far, slow_near)[0], np.array([5.5, 3.0, 0.5], F) / F(5))


def test_every_evaluated_object_gets_its_own_leader():
    leader = (F(12) + F(2.5) * T, 0.0, 4.0, 2.0, 0.0)
    out = ttc(FOLLOWER, leader, num_evaluated=2)
    assert out.shape == (2, 3)
    np.testing.assert_array_equal(out[1], 5.0)  # nobody ahead of the leader


def test_ego_frame_rotation():
    # The same follow scene driven along +y: equal up to float32 rounding of cos/sin(pi/2).
    heading = F(math.pi / 2)
    follower = (0.0, F(5) * T, 4.0, 2.0, heading)
    leader = (0.0, F(12) + F(2.5) * T, 4.0, 2.0, heading)
    np.testing.assert_allclose(ttc(follower, leader)[0], np.array([5.5, 3.0, 0.5]) / 5, atol=1e-5)


@pytest.mark.parametrize(
    "yaw_deg, lateral_overlap, followed",
    [
        (20.0, -0.8, True),  # turned 20 degrees but well inside the path
        (20.0, -0.3, False),  # small overlap needs a heading difference <= 10 degrees
        (5.0, -0.3, True),
        (80.0, -1.5, False),  # beyond 75 degrees
    ],
)
def test_heading_and_lateral_overlap_rules(yaw_deg, lateral_overlap, followed):
    yaw = math.radians(yaw_deg)
    # The leader's half extents seen from the follower's frame.
    long_offset = 2 * abs(math.cos(yaw)) + 1 * abs(math.sin(yaw))
    lat_offset = 2 * abs(math.sin(yaw)) + 1 * abs(math.cos(yaw))
    rel_y = lateral_overlap + 1 + lat_offset
    leader = (F(20) + F(2.5) * T, F(rel_y), 4.0, 2.0, yaw)
    out = ttc(FOLLOWER, leader)[0]
    if followed:
        gap = 20 + 2.5 * np.arange(1, 4) - 5 * np.arange(1, 4) - 2 - long_offset
        np.testing.assert_allclose(out, np.minimum(gap / 5, 5), rtol=1e-5)
        assert np.all(out < 5)
    else:
        np.testing.assert_array_equal(out, 5.0)


def test_heading_difference_is_not_wrapped():
    # As officially, the heading difference is |h_other - h_ego| without
    # wrapping: two cars both heading almost exactly -x, one at +3.1 rad and
    # the other at -3.1 rad, differ by 6.2 rad and are not a leader/follower pair.
    follower = (F(-5) * T, 0.0, 4.0, 2.0, 3.1)
    leader = (F(-12) - F(2.5) * T, 0.0, 4.0, 2.0, -3.1)
    np.testing.assert_array_equal(ttc(follower, leader), 5.0)
    same_sign = (F(-12) - F(2.5) * T, 0.0, 4.0, 2.0, 3.1)
    assert np.all(ttc(follower, same_sign) < 5.0)


def test_all_steps_with_nan_speeds_at_the_ends():
    leader = (F(12) + F(2.5) * T, 0.0, 4.0, 2.0, 0.0)
    x = np.stack([FOLLOWER[0], leader[0]])
    zeros = np.zeros_like(x)
    full = time_to_collision(
        x, zeros, zeros + 4, zeros + 2, zeros, np.ones(x.shape, bool), num_evaluated=1, seconds_per_step=DT
    )
    assert full.shape == (1, STEPS)
    # At the first and last step the speeds are NaN: no closing speed, 5 s.
    assert full[0, 0] == 5.0 and full[0, -1] == 5.0
    np.testing.assert_array_equal(full[0, 1:4], np.array([5.5, 3.0, 0.5], F) / F(5))


def random_traffic(rng, samples=5, objects=12, steps=91):
    """Boxes drifting along a few lanes, so that there are neighbours and leaders."""
    lane = rng.integers(0, 3, objects)
    x = rng.uniform(0, 60, (samples, objects, 1)) + np.arange(steps) * rng.uniform(0.5, 1.5, (samples, objects, 1))
    y = (lane * 3.5)[None, :, None] + rng.normal(0, 0.3, (samples, objects, steps))
    heading = rng.normal(0, 0.1, (samples, objects, steps))
    length = np.broadcast_to(rng.uniform(3.5, 5, (1, objects, 1)), x.shape)
    width = np.broadcast_to(rng.uniform(1.6, 2.1, (1, objects, 1)), x.shape)
    valid = rng.random(x.shape) > 0.05
    return [np.ascontiguousarray(a, np.float32) for a in (x, y, length, width, heading)] + [valid]


def test_chunks_over_samples_give_the_same_results(monkeypatch):
    rng = np.random.default_rng(11)
    x, y, length, width, heading, valid = random_traffic(rng)
    steps = slice(11, None)
    cos_h, sin_h = cos32(heading[..., steps]), sin32(heading[..., steps])
    nearest_args = (
        x[..., steps],
        y[..., steps],
        length[..., steps],
        width[..., steps],
        cos_h,
        sin_h,
        valid[..., steps],
        4,
    )
    whole_nearest = interaction.distance_to_nearest_object(*nearest_args)
    ttc_args = (x, y, length, width, heading, valid)
    ttc_options = {"num_evaluated": 4, "seconds_per_step": 0.1, "steps": steps}
    whole_ttc = time_to_collision(*ttc_args, **ttc_options)
    assert (whole_ttc < following.MAXIMUM_TIME_TO_COLLISION).any()
    monkeypatch.setattr(interaction, "PAIRS_PER_CHUNK", 4 * 12 * 91 * 2)  # two samples per chunk
    assert len(interaction._sample_chunks(5, 4 * 12 * 91)) == 3
    np.testing.assert_array_equal(interaction.distance_to_nearest_object(*nearest_args), whole_nearest)
    np.testing.assert_array_equal(time_to_collision(*ttc_args, **ttc_options), whole_ttc)


def all_objects_reference(x, y, length, width, heading, valid, num_evaluated, speed):
    """The official all-objects time to collision at every step (`all_objects_time_to_collision`)."""
    from wosac_eval.features.float32_math import packet_tail, sincos32

    num_objects, num_steps = x.shape[-2:]
    pair_tail = packet_tail((num_steps, num_evaluated, num_objects))
    ego_tail = packet_tail((num_steps, num_evaluated, 1))
    t = lambda a: np.swapaxes(a, -1, -2)  # noqa: E731  (..., steps, objects)
    with np.errstate(invalid="ignore", over="ignore"):
        ego_sin, ego_cos = sincos32(-t(heading)[..., :num_evaluated, None], ego_tail)
        ahead, beside, yaw_diff = following.ego_frame_offsets(
            t(x), t(y), t(length), t(width), t(heading), ego_cos, ego_sin, num_evaluated
        )
        pairs = following.FollowedPairs(
            ahead,
            beside,
            yaw_diff,
            pair_tail,
            t(length)[..., None, :],
            t(width)[..., None, :],
            t(valid)[..., None, :],
        )
        out = following.all_objects_time_to_collision(pairs, t(speed), num_evaluated)
    return t(out)


def test_pruned_search_equals_all_objects_with_nan_and_infinite_speeds():
    """NaN speeds (every track's first and last steps, and some more) leave the pruned search in place and
    equal to the all-objects one; an infinite speed sends its step to the all-objects search (a closing
    speed of +inf gives 0 s even where nothing is followed)."""
    from wosac_eval.features.kinematics import linear_speed

    rng = np.random.default_rng(21)
    x, y, length, width, heading, valid = random_traffic(rng, samples=4, objects=10, steps=40)
    with np.errstate(invalid="ignore"):
        speed = linear_speed(x, y, np.zeros_like(x), 0.1)
    assert np.isnan(speed[..., 0]).all() and np.isnan(speed[..., -1]).all()
    speed[0, 3, 7] = np.nan
    speed[1, 0, 12] = np.inf
    speed[2, 5, 20] = -np.inf
    got = time_to_collision(x, y, length, width, heading, valid, num_evaluated=4, seconds_per_step=0.1, speed=speed)
    want = all_objects_reference(x, y, length, width, heading, valid, 4, speed)
    assert (got < following.MAXIMUM_TIME_TO_COLLISION).any()
    np.testing.assert_array_equal(got, want)


def test_an_infinite_speed_where_nothing_is_followed_is_the_official_zero():
    """Officially the nearest object by masked gap is taken even where nothing is followed (its gap about
    1e10, so in float32 an object 2 km behind is "nearer" than the object itself): a closing speed of
    +inf then gives 0 s, not the cap. Such a step is searched over all objects."""
    steps = 5
    x = np.stack([np.full(steps, 10.0), np.full(steps, -1990.0)]).astype(F)
    zeros = np.zeros_like(x)
    speed = np.full(x.shape, 5.0, F)
    speed[0, 2] = np.inf
    valid = np.ones(x.shape, bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        got = time_to_collision(
            x, zeros, zeros + 4, zeros + 2, zeros, valid, num_evaluated=1, seconds_per_step=0.1, speed=speed
        )
    want = all_objects_reference(x, zeros, zeros + 4, zeros + 2, zeros, valid, 1, speed)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got[0], [5, 5, 0, 5, 5])


def test_the_lowest_bound_is_the_first_strict_minimum():
    """`_lowest` over `_bounds_of_step` picks what a scan keeping the first strict minimum of the raw bounds
    picks: ties to the lowest index, NaN and unsearched boxes never, -1 if none."""
    rng = np.random.default_rng(3)
    for trial in range(300):
        n = int(rng.integers(1, 40))
        x = rng.choice([0.0, 1.0, 2.5, -3.0], n).astype(F) if trial % 2 else rng.normal(0, 20, n).astype(F)
        y = rng.choice([0.0, 1.0, -1.0], n).astype(F) if trial % 3 else rng.normal(0, 20, n).astype(F)
        reach = rng.choice([0.5, 1.0, 2.5, -np.inf], n).astype(F)
        x[rng.random(n) < 0.1] = np.nan
        if trial % 5 == 0:
            x[:], y[:] = 0.0, 0.0  # coincident boxes: ties everywhere
        e = int(rng.integers(0, n))
        if not reach[e] > -np.inf:
            continue
        with np.errstate(invalid="ignore"):
            raw = np.sqrt((x - x[e]) ** 2 + (y - y[e]) ** 2) * interaction.BOUND_SCALE - (
                (reach[e] + reach) + interaction.BOUND_MARGIN
            )
        raw[e] = np.inf
        want, best = -1, F(np.inf)
        for o, value in enumerate(raw):
            if value < best:
                want, best = o, value
        lower = np.empty(n, F)
        interaction._bounds_of_step(x, y, reach, e, lower)
        assert interaction._lowest(lower) == want, (trial, raw, want)
