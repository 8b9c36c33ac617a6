"""Tests of red-light violations and the nearest-lane search on hand-built lanes."""

import numpy as np
import pytest

from wosac_eval.arrays.scenario import TrafficSignals
from wosac_eval.features import traffic_lights

F = np.float32
ARROW_STOP, STOP, CAUTION, GO, FLASHING_STOP = 1, 4, 5, 6, 7


def lane(*xy):
    p = np.array(xy, np.float64)
    return np.concatenate([p, np.zeros((len(p), 1))], axis=1).astype(F)


# Two straight lanes along +x, 20 m apart, points every 10 m.
MAIN = lane(*[(x, 0) for x in range(0, 101, 10)])
SIDE = lane(*[(x, 20) for x in range(0, 101, 10)])
MAIN_ID, SIDE_ID = 101, 202
STOP_POINT = (55.0, 0.0)  # mid-segment on the main lane


@pytest.fixture(scope="module")
def lanes():
    return traffic_lights.build_lane_table([MAIN, SIDE], [MAIN_ID, SIDE_ID])


def signals(states, lane_id=MAIN_ID, stop_point=STOP_POINT):
    """One signal; `states` per step."""
    states = np.asarray(states, np.int32)[:, None]
    stop = np.broadcast_to(np.asarray(stop_point, F), (len(states), 1, 2)).copy()
    return TrafficSignals(lane_id=np.array([lane_id], np.int64), state=states, stop_point=stop)


def violations(lanes, xs, ys, sig, valid=None):
    x = np.atleast_2d(np.asarray(xs, F))
    y = np.broadcast_to(np.atleast_2d(np.asarray(ys, F)), x.shape)
    valid = np.ones(x.shape, bool) if valid is None else np.atleast_2d(np.asarray(valid, bool))
    return traffic_lights.red_light_violation(x, y, valid, lanes, sig)


CROSSING = [45, 50, 53, 57, 61]  # passes x = 55 between steps 2 and 3


def test_crossing_on_stop_violates_at_the_crossing_step_only(lanes):
    out = violations(lanes, CROSSING, 0.0, signals([STOP] * 5))
    assert out.shape == (1, 5) and out.dtype == bool
    np.testing.assert_array_equal(out, [[False, False, False, True, False]])


def test_arrow_stop_counts_as_stop(lanes):
    np.testing.assert_array_equal(
        violations(lanes, CROSSING, 0.0, signals([ARROW_STOP] * 5)), [[False, False, False, True, False]]
    )


@pytest.mark.parametrize("state", [GO, CAUTION, FLASHING_STOP, 0])
def test_crossing_on_other_states_is_fine(lanes, state):
    assert not violations(lanes, CROSSING, 0.0, signals([state] * 5)).any()


def test_state_at_the_crossing_step_decides(lanes):
    # Red until step 2, green when crossing at step 3: fine.
    assert not violations(lanes, CROSSING, 0.0, signals([STOP, STOP, STOP, GO, GO])).any()
    # Green until step 2, red at step 3: violation.
    np.testing.assert_array_equal(
        violations(lanes, CROSSING, 0.0, signals([GO, GO, GO, STOP, STOP])), [[False, False, False, True, False]]
    )


def test_stopping_before_the_stop_point(lanes):
    assert not violations(lanes, [45, 50, 53, 54.5, 54.9], 0.0, signals([STOP] * 5)).any()


def test_already_past_the_stop_point(lanes):
    assert not violations(lanes, [56, 60, 65, 70, 75], 0.0, signals([STOP] * 5)).any()


def test_reversing_across_the_stop_point(lanes):
    assert not violations(lanes, [61, 57, 53, 50, 45], 0.0, signals([STOP] * 5)).any()


def test_crossing_on_another_lane(lanes):
    # Same x motion on the side lane, whose state is unknown: the main lane's red does not apply.
    assert not violations(lanes, CROSSING, 20.0, signals([STOP] * 5)).any()


def test_signal_on_the_side_lane_applies_to_the_side_lane(lanes):
    side = signals([STOP] * 5, lane_id=SIDE_ID, stop_point=(55.0, 20.0))
    np.testing.assert_array_equal(violations(lanes, CROSSING, 20.0, side), [[False, False, False, True, False]])
    assert not violations(lanes, CROSSING, 0.0, side).any()


def test_invalid_at_the_crossing_step(lanes):
    valid = [True, True, True, False, True]
    assert not violations(lanes, CROSSING, 0.0, signals([STOP] * 5), valid=valid).any()


def test_signal_for_an_unknown_lane(lanes):
    assert not violations(lanes, CROSSING, 0.0, signals([STOP] * 5, lane_id=999)).any()


def test_batched_rollouts_and_objects(lanes):
    x = np.array([[CROSSING, [45, 50, 53, 54, 54]], [[40, 45, 50, 54, 56], CROSSING]], F)  # (2, 2, 5)
    y = np.zeros_like(x)
    out = traffic_lights.red_light_violation(x, y, np.ones(x.shape, bool), lanes, signals([STOP] * 5))
    assert out.shape == (2, 2, 5)
    expected = np.zeros((2, 2, 5), bool)
    expected[0, 0, 3] = expected[1, 0, 4] = expected[1, 1, 3] = True
    np.testing.assert_array_equal(out, expected)


def test_no_lanes_or_no_signals(lanes):
    x = np.array([CROSSING], F)
    assert traffic_lights.build_lane_table([lane((1, 1))], [5]) is None
    for table, sig in ((None, signals([STOP] * 5)), (lanes, None)):
        out = traffic_lights.red_light_violation(x, x * 0, np.ones(x.shape, bool), table, sig)
        assert out.shape == (1, 5) and not out.any()


def test_signal_steps_must_match(lanes):
    with pytest.raises(ValueError, match="dynamic map states"):
        violations(lanes, CROSSING, 0.0, signals([STOP] * 4))


# --- The nearest-lane measure ---------------------------------------------------------------------


def test_lane_table_layout_keeps_the_padding_segment():
    # Lanes of 3 and 2 points are padded to 3 points; the shorter lane's
    # segment from its last point to the origin counts as valid (as officially).
    table = traffic_lights.build_lane_table([lane((1, 1), (2, 1), (3, 1)), lane((5, 5), (6, 5))], [7, 8])
    assert table.num_segments == 2
    np.testing.assert_array_equal(table.valid, [True, True, True, True])
    np.testing.assert_array_equal(table.start, [[1, 1], [2, 1], [5, 5], [6, 5]])
    np.testing.assert_array_equal(table.delta, [[1, 0], [1, 0], [1, 0], [-6, -5]])
    np.testing.assert_array_equal(table.lane_ids, [7, 8])


def test_lane_table_marks_padding_starts_invalid():
    table = traffic_lights.build_lane_table([lane((1, 1), (2, 1), (3, 1), (4, 1)), lane((5, 5), (6, 5))], [7, 8])
    np.testing.assert_array_equal(table.valid, [True, True, True, True, True, False])


def test_measure_is_p_plus_t_d():
    # The point (5, 0) lies on lane A, yet its measure there is |p + t d| = 10,
    # while lane B's first segment starts 3.04 m away: B is "nearest".
    a = lane((0, 0), (10, 0))
    b = lane((5.5, 3), (5.5, 13))
    table = traffic_lights.build_lane_table([a, b], [1, 2])
    seg = traffic_lights.nearest_lane_segment(table, np.array([[5, 0], [0.5, 0]], F))
    np.testing.assert_array_equal(seg // table.num_segments, [1, 0])


def lane_measure(xy, start, delta):
    """|p + clamp(t) d| with the same float32 operations as the official code."""
    px = xy[:, None, 0] - start[None, :, 0]
    py = xy[:, None, 1] - start[None, :, 1]
    along = px * delta[None, :, 0] + py * delta[None, :, 1]
    squared = delta[None, :, 0] * delta[None, :, 0] + delta[None, :, 1] * delta[None, :, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip(np.where(squared == 0, F(0), along / squared), F(0), F(1))
    mx, my = px + delta[None, :, 0] * t, py + delta[None, :, 1] * t
    return np.sqrt(mx * mx + my * my)


def test_nearest_lane_segment_equals_brute_force():
    rng = np.random.default_rng(42)
    lanes, ids = [], []
    for k in range(60):
        n = int(rng.integers(2, 30))
        step = rng.uniform(0.2, 15, n)
        angle = np.cumsum(rng.normal(0, 0.3, n)) + rng.uniform(-np.pi, np.pi)
        xy = rng.uniform(-200, 200, 2) + np.cumsum(np.stack([step * np.cos(angle), step * np.sin(angle)], 1), 0)
        lanes.append(np.concatenate([xy, np.zeros((n, 1))], 1).astype(F))
        ids.append(1000 + k)
    table = traffic_lights.build_lane_table(lanes, ids)
    points = np.concatenate(
        [
            rng.uniform(-260, 260, (3000, 2)),
            np.concatenate(lanes)[::3, :2],  # exactly on lane points
            np.array([[0.0, 0.0], [5000.0, -5000.0]]),  # the padding target, and far away
        ]
    ).astype(F)
    ours = traffic_lights.nearest_lane_segment(table, points)
    valid = np.flatnonzero(table.valid)
    measure = lane_measure(points, table.start[valid], table.delta[valid])
    reference = valid[np.argmin(measure, axis=1)]  # first minimum: lowest segment index
    mismatch = np.flatnonzero(ours != reference)
    assert mismatch.size == 0, f"{mismatch.size} mismatches, e.g. point {points[mismatch[0]]}"


def test_compiled_crossings_equal_the_array_kernel():
    """The compiled loop of numpy's red-light search and `stop_line_crossings` (the array kernel JAX runs)
    give the same crossings bit for bit, with points exactly on a line, segments of no length and NaN."""
    rng = np.random.default_rng(4)
    samples, objects, steps, signals = 3, 7, 30, 5
    x = np.cumsum(rng.normal(0.8, 1.0, (samples, objects, steps)), axis=-1).astype(np.float32)
    y = rng.normal(0, 3, (samples, objects, steps)).astype(np.float32)
    x[0, 1, 4], y[1, 2, 9] = np.nan, np.inf
    valid = rng.random(x.shape) > 0.1
    seg_start = rng.normal(10, 5, (steps, signals, 2)).astype(np.float32)
    seg_delta = rng.normal(0, 2, (steps, signals, 2)).astype(np.float32)
    seg_delta[:, 0] = 0  # a segment of no length: every point at 0
    stop_point = seg_start + rng.normal(0, 1, seg_start.shape).astype(np.float32)
    stop_point[:, 1] = seg_start[:, 1]  # the stop point at the segment's start
    x[2, 3, :] = stop_point[:, 2, 0]  # an object exactly on a stop point at every step
    stopping = rng.random((steps, signals)) > 0.3
    want = traffic_lights.stop_line_crossings(np.stack([x, y], -1), valid, seg_start, seg_delta, stop_point, stopping)
    got, crossed_any = traffic_lights.compiled_stop_line_crossings(
        x, y, valid, seg_start, seg_delta, stop_point, stopping
    )
    assert want.any()
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(crossed_any, want.any(axis=-1))


def stop_point_segments_step_by_step(table, sig):
    """The definition: at every step, each signal's lane segment nearest its stop point (lowest on ties)."""
    match = table.lane_ids[None, :] == sig.lane_id[:, None]
    lane_index = np.argmax(match, axis=1)
    pts = table.points[lane_index]
    seg_valid = table.valid.reshape(len(table.lane_ids), -1)[lane_index]
    start, delta = pts[:, :-1], pts[:, 1:] - pts[:, :-1]
    d = traffic_lights.lane_measure(sig.stop_point[:, :, None, :], start[None], delta[None])
    seg = np.argmin(np.where(seg_valid[None], d, F(1e10)), axis=-1)
    signal = np.arange(len(sig.lane_id))[None, :]
    return pts[signal, seg], pts[signal, seg + 1] - pts[signal, seg], np.broadcast_to(match.any(axis=1), seg.shape)


@pytest.mark.parametrize("seed", range(4))
def test_stop_point_segments_measure_each_step_as_the_definition(seed):
    """Stop points measured where they change give every step's segment: points that stay, move at some steps,
    come back, jump between lanes, sit on a segment's end (ties), are NaN or -0.0; lanes of different lengths,
    a lane no signal names and a signal on an unknown lane."""
    rng = np.random.default_rng(seed)
    lanes_xy = [lane(*[(x, 7.0 * k + rng.normal(0, 0.5)) for x in range(0, 10 * (3 + 2 * k), 10)]) for k in range(4)]
    table = traffic_lights.build_lane_table(lanes_xy, [10, 11, 12, 13])
    steps, num_signals = 91, 6
    ids = np.array([10, 11, 12, 10, 99, 13], np.int64)
    stop = np.broadcast_to(rng.uniform(0, 40, (1, num_signals, 2)).astype(F), (steps, num_signals, 2)).copy()
    stop[30:60, 0] = rng.uniform(0, 40, 2)  # moves, then comes back
    stop[::7, 1] = rng.uniform(-10, 50, (len(range(0, steps, 7)), 2))  # jumps every 7th step
    stop[:, 2] = (20.0, 14.0)  # on a segment's end: two segments tie
    stop[45:, 3] = np.nan
    stop[10:, 5] = (-0.0, 21.0)
    stop[20:, 5] = (0.0, 21.0)
    sig = TrafficSignals(lane_id=ids, state=np.full((steps, num_signals), STOP, np.int32), stop_point=stop)
    for got, want in zip(
        traffic_lights.stop_point_segments(table, sig), stop_point_segments_step_by_step(table, sig), strict=True
    ):
        np.testing.assert_array_equal(got, want, strict=True)
