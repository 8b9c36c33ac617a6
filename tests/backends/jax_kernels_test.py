"""The dense JAX drivers (features/dense.py) and the kernels under `jax.jit` against numpy, on random inputs.

Random inputs reach corners the scenario data may miss: huge angles, the
libm tail, degenerate segments, points past segment ends, ties.
"""

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest

import jax
import jax.numpy as jnp

from wosac_eval.backends import jax_backend, jax_driver
from wosac_eval.features import (
    box_geometry,
    dense,
    dense_chunks,
    dense_road_edge,
    following,
    interaction,
    map_arrays,
    road_edge,
    traffic_lights,
)
from wosac_eval.features.float32_math import sincos32
from wosac_eval.features.ops import fma32
from wosac_eval.features.search_strategy import TimeToCollisionInputs
from wosac_eval.features.spatial import NON_FINITE_PREFIX
from wosac_eval.features.xp import array_namespace, divide

F = np.float32


def jitted(fn, *args):
    with jax.enable_x64(True):
        return jax.tree_util.tree_map(np.asarray, jax.jit(fn)(*args))


def test_namespace_dispatch():
    assert array_namespace(np.zeros(2)) is np
    assert array_namespace(np.zeros(2), jnp.zeros(2)) is jnp
    assert array_namespace(None, 1.0) is np


def test_sincos_fma_and_divide_under_jit_and_vmap():
    rng = np.random.default_rng(0)
    x = np.concatenate(
        [
            rng.normal(0, 4, 4000),
            rng.uniform(-1e5, 1e5, 1000),
            [0.0, -0.0, 25966.0, 18838.0, 1e30, np.inf, -np.inf, np.nan],
        ]
    ).astype(F)
    tail = rng.random(x.shape) < 0.2
    with np.errstate(invalid="ignore"):  # libm's sin(inf) is NaN, with a warning
        want_all = sincos32(x, tail)
    for got, want in zip(jitted(sincos32, x, tail), want_all):
        np.testing.assert_array_equal(got, want)
    a, b, c = (rng.normal(size=5000).astype(F) for _ in range(3))
    np.testing.assert_array_equal(jitted(fma32, a, b, c), fma32(a, b, c))
    rows = rng.normal(size=(6, 500, 40)).astype(F)
    divisor = rng.normal(size=(1, 40)).astype(F)
    # A broadcast divisor, plain and under vmap: the reciprocal rewrite must not apply.
    np.testing.assert_array_equal(jitted(divide, rows, divisor), rows / divisor)
    np.testing.assert_array_equal(jitted(jax.vmap(lambda r: divide(r, F(0.1))), rows), rows / F(0.1))


def random_boxes(rng, n):
    x, y = rng.uniform(-20, 20, n).astype(F), rng.uniform(-20, 20, n).astype(F)
    length, width = rng.uniform(0.5, 6, n).astype(F), rng.uniform(0.5, 3, n).astype(F)
    heading = rng.uniform(-4, 4, n).astype(F)
    return x, y, length, width, heading


def test_nearest_object_dense_equals_numpy():
    rng = np.random.default_rng(1)
    objects, steps, evaluated = 12, 7, 5
    x, y, length, width, heading = (a.reshape(objects, steps) for a in random_boxes(rng, objects * steps))
    valid = rng.random((objects, steps)) < 0.85
    sin_h, cos_h = sincos32(heading)
    expected = interaction.distance_to_nearest_object(x, y, length, width, cos_h, sin_h, valid, evaluated)
    got = jitted(lambda *a: dense.nearest_object_distance(*a, evaluated), x, y, length, width, cos_h, sin_h, valid)
    np.testing.assert_array_equal(got, expected)


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_nearest_object_pruned_on_the_device_equals_numpy_in_crowds_and_apart():
    """Many boxes: rows the candidate bound settles (boxes apart) and rows it does not (a crowd of
    touching boxes, a huge box), both equal to the numpy search bit for bit."""
    rng = np.random.default_rng(11)
    objects, steps, evaluated = 40, 9, 12
    x, y, length, width, heading = (a.reshape(objects, steps) for a in random_boxes(rng, objects * steps))
    x, y = x * F(8), y * F(8)  # most boxes far apart
    x[:10], y[:10] = x[:10] / F(40), y[:10] / F(40)  # a crowd around the origin, evaluated boxes among it
    length[20, 4], width[20, 4] = F(600), F(300)  # over 256 m wide: every pair at its step
    valid = rng.random((objects, steps)) < 0.9
    sin_h, cos_h = sincos32(heading)
    expected = interaction.distance_to_nearest_object(x, y, length, width, cos_h, sin_h, valid, evaluated)
    got = jitted(lambda *a: dense.nearest_object_distance(*a, evaluated), x, y, length, width, cos_h, sin_h, valid)
    np.testing.assert_array_equal(got, expected)
    radius = interaction.corner_radius(length, width)
    outlines = interaction.box_outlines(x, y, length - 2 * radius, width - 2 * radius, cos_h, sin_h)
    _, settled = jitted(
        lambda *a: dense._nearest_object_candidates(*a, evaluated),
        x,
        y,
        length,
        width,
        cos_h,
        sin_h,
        outlines,
        radius,
        valid,
    )
    assert settled.mean() > 0.5 and not settled[:, 4][valid[:evaluated, 4]].any() and not settled.all()


def test_time_to_collision_dense_equals_numpy():
    rng = np.random.default_rng(2)
    objects, steps, evaluated = 10, 9, 4
    # A convoy along x with jitter, so that many pairs follow each other.
    x = (
        np.arange(objects)[:, None] * 7.0
        + np.arange(steps)[None] * rng.uniform(0.5, 2, (objects, 1))
        + rng.normal(0, 0.3, (objects, steps))
    ).astype(F)
    y = rng.normal(0, 1.0, (objects, steps)).astype(F)
    heading = rng.normal(0, 0.2, (objects, steps)).astype(F)
    length, width = np.full((objects, steps), F(4.5)), np.full((objects, steps), F(2.0))
    valid = rng.random((objects, steps)) < 0.9
    steps_eval = slice(1, steps)
    boxes = {"x": x, "y": y, "length": length, "width": width, "heading": heading, "valid": valid}
    expected = following.time_to_collision(
        TimeToCollisionInputs(**boxes, num_evaluated=evaluated, seconds_per_step=0.1, steps=steps_eval)
    )
    assert (expected < following.MAXIMUM_TIME_TO_COLLISION).any()
    from wosac_eval.features.float32_math import packet_tail
    from wosac_eval.features.kinematics import linear_speed

    speed = linear_speed(x, y, np.zeros_like(x), 0.1)
    # Object-major, the official (step-major) tails transposed as the pairs.
    object_major = lambda tail: np.ascontiguousarray(np.transpose(tail[steps_eval], (1, 2, 0)))
    ego_tail = object_major(packet_tail((steps, evaluated, 1)))
    pair_tail = object_major(packet_tail((steps, evaluated, objects)))
    got = jitted(
        lambda *a: dense.time_to_collision(*a[:7], ego_tail=a[7], pair_tail=a[8], num_evaluated=evaluated),
        *(a[:, steps_eval] for a in (x, y, length, width, heading, speed, valid)),
        ego_tail,
        pair_tail,
    )
    np.testing.assert_array_equal(got, expected)


def test_jax_searches_are_search_strategies():
    from support.strategies import assert_is_search_strategy
    from wosac_eval.backends.host_search import HostSearch, HostSearches

    assert_is_search_strategy(dense.DenseSearch({}))
    assert_is_search_strategy(HostSearch(HostSearches(()), 0))


def test_road_edge_dense_equals_numpy():
    rng = np.random.default_rng(3)
    # A closed loop, an open zig-zag with a repeated point (degenerate segment) and a ramp.
    loop = np.array([[0, 0, 0], [40, 0, 0], [40, 30, 0], [0, 30, 0], [0, 0, 0]], F)
    zigzag = np.array([[-10, -10, 0], [0, -15, 0], [0, -15, 0], [10, -10, 0], [20, -18, 1]], F)
    ramp = np.array([[50, -5, 0], [50, 40, 12]], F)
    table = road_edge.build_segment_table([loop, zigzag, ramp])
    queries = np.concatenate(
        [rng.uniform([-20, -30, -1], [60, 50, 8], (3000, 3)), loop[:4] + F(0.0), [[45, 30, 0], [-3, -4, 0]]]
    ).astype(F)
    expected = road_edge.signed_distance_to_polylines(table, queries)
    segments = map_arrays.segment_table_arrays(table)
    got = jitted(dense_road_edge.signed_distance_to_road_edge, queries, segments)
    np.testing.assert_array_equal(got, expected)
    # Padded segments and a small chunk (several lax.map steps) change nothing.
    padded = {
        k: v if k in dense_road_edge.CELL_KEYS or k.startswith(NON_FINITE_PREFIX) else jax_driver.pad_axis(v, 64, 0)
        for k, v in segments.items()
    }
    old = dense_chunks.PAIRS_PER_CHUNK
    dense_chunks.PAIRS_PER_CHUNK = 64 * 100
    try:
        np.testing.assert_array_equal(jitted(dense_road_edge.signed_distance_to_road_edge, queries, padded), expected)
    finally:
        dense_chunks.PAIRS_PER_CHUNK = old


def random_road_edges(rng, count):
    """Random-walk polylines (some closed, some climbing) over a 300 m square: thousands of segments."""
    lines = []
    for k in range(count):
        n = int(rng.integers(20, 80))
        steps = rng.normal(0, 1.0, (n, 3)) * [3.0, 3.0, 0.15] + [rng.uniform(-1, 1), rng.uniform(-1, 1), 0]
        line = (rng.uniform(-150, 150, 3) * [1, 1, 0.02] + np.cumsum(steps, axis=0)).astype(F)
        if k % 7 == 0:
            line = np.concatenate([line, line[:1]])  # closed
        lines.append(line)
    return lines


def test_road_edge_segments_shared_by_a_stack_of_scenes_change_nothing():
    """`jax_driver.vmap_scenes` gathers every scene's candidates from one table of the stack's segments
    (`dense_road_edge.shared_segments`): each scene's distances are still its own, padding and fallback included."""
    rng = np.random.default_rng(11)
    scenes = []
    for count in (12, 20):
        table = road_edge.build_segment_table(random_road_edges(rng, count))
        on_map = rng.uniform([-170, -170, -3], [170, 170, 3], (600, 3))
        far = rng.uniform([-5e3, -5e3, -50], [5e3, 5e3, 50], (40, 3))  # off the grid: the fallback
        queries = np.concatenate([on_map, far]).astype(F)
        scenes.append((road_edge.signed_distance_to_polylines(table, queries), queries, table))
    arrays = [map_arrays.segment_table_arrays(table) for _, _, table in scenes]
    sizes = {k: max(a[k].shape[0] for a in arrays) for k in arrays[0]}
    padded = [
        {k: v if k.startswith(NON_FINITE_PREFIX) else jax_driver.pad_axis(v, sizes[k], 0) for k, v in a.items()}
        for a in arrays
    ]
    assert padded[0]["start"].shape[0] > len(scenes[0][2].start)  # the smaller scene is padded
    stack = jax_driver.stacked(padded)
    _, axes = dense_road_edge.shared_segments(stack)
    assert axes["shared_start"] is None and axes["start"] == 0  # one table, not one per scene
    got = jitted(
        jax_driver.vmap_scenes(dense_road_edge.signed_distance_to_road_edge), np.stack([q for _, q, _ in scenes]), stack
    )
    for (expected, _, _), distances in zip(scenes, got):
        np.testing.assert_array_equal(distances, expected)


@pytest.mark.parametrize("candidates", [2, 8, road_edge.CELL_CANDIDATES])
@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_road_edge_cell_search_never_misses_the_nearest(monkeypatch, candidates):
    """The cell tables never leave out the nearest segment (nor a tie at a lower index): every settled
    query equals the brute-force all-pairs search; the queries they do not settle (off the grid, far
    from every edge, on another level) fall back to every segment. Both paths run here."""
    rng = np.random.default_rng(5)
    table = road_edge.build_segment_table(random_road_edges(rng, 60))
    segments = map_arrays.segment_table_arrays(table)
    cells = road_edge.cell_candidate_table(segments["start"], segments["delta"], k=candidates)
    segments.update({f"cell_{k}": v for k, v in cells.items()})
    on_map = rng.uniform([-170, -170, -3], [170, 170, 3], (4000, 3))
    on_segments = segments["start"][rng.integers(0, len(segments["start"]), 300)]  # exact ties
    elevated = on_map[:200] + [0, 0, 40]  # near an edge in the plane, far in height
    far = rng.uniform([-5e3, -5e3, -50], [5e3, 5e3, 50], (200, 3))
    queries = np.concatenate([on_map, on_segments, elevated, far]).astype(F)
    expected = road_edge.signed_distance_to_polylines(table, queries)
    monkeypatch.setattr(dense_road_edge, "FALLBACK_CHUNK", 64)  # several fallback rounds
    np.testing.assert_array_equal(jitted(dense_road_edge.signed_distance_to_road_edge, queries, segments), expected)
    seg = {k: v for k, v in segments.items() if k not in dense_road_edge.CELL_KEYS}
    cell = {k: segments[k] for k in dense_road_edge.CELL_KEYS}
    best, settled = jitted(dense_road_edge._nearest_listed_segment, queries, seg, cell)
    brute = jitted(dense_road_edge._nearest_segment_all, queries, seg)
    np.testing.assert_array_equal(best[settled], brute[settled])
    assert 0 < settled.sum() < len(queries)  # both the tables and the fallback ran
    print(f"{candidates} candidates per cell: {settled.mean():.1%} of the queries settled by the table")
    assert not settled[-len(far) :].any()
    # Padded segments and grid rows change nothing; unneeded queries are never searched exhaustively.
    padded = {
        k: v
        if k in ("cell_origin", "cell_shape") or k.startswith(NON_FINITE_PREFIX)
        else jax_driver.pad_axis(v, len(v) + 50, 0)
        for k, v in segments.items()
    }
    np.testing.assert_array_equal(jitted(dense_road_edge.signed_distance_to_road_edge, queries, padded), expected)
    needed = rng.random(len(queries)) < 0.5
    got = jitted(lambda q, n: dense_road_edge.signed_distance_to_road_edge(q, segments, n), queries, needed)
    np.testing.assert_array_equal(got[needed], expected[needed])


def test_road_edge_box_distances_equal_numpy():
    """`DenseSearch.road_edge_distance` (corners searched, their NaN-spreading maximum in one reduction)
    equals numpy's box distances, with boxes on and off the grid, huge, NaN and far from every edge."""
    rng = np.random.default_rng(6)
    table = road_edge.build_segment_table(random_road_edges(rng, 60))
    segments = map_arrays.segment_table_arrays(table)
    n = 3000
    x, y = (rng.uniform(-170, 170, n).astype(F) for _ in range(2))
    bottom = rng.uniform(-3, 3, n).astype(F)
    length, width = rng.uniform(0.5, 12, n).astype(F), rng.uniform(0.5, 4, n).astype(F)
    heading = rng.uniform(-4, 4, n).astype(F)
    x[:100] = rng.choice([-1, 1], 100) * rng.uniform(1e3, 5e3, 100)  # off the grid, far from every edge
    length[100:110] = 300  # huge: its corners are far from the centre's cell
    x[110], heading[111], bottom[112] = np.nan, np.nan, np.inf
    sin_h, cos_h = sincos32(heading)
    valid = rng.random(n) < 0.9
    boxes = [a.reshape(30, -1) for a in (x, y, bottom, length, width, cos_h, sin_h, valid)]  # (objects, steps)
    expected = road_edge.box_distance_to_road_edge(*boxes, table)
    got = jitted(dense.DenseSearch(segments).road_edge_distance, *boxes)
    np.testing.assert_array_equal(got, expected)


def test_lane_search_dense_equals_numpy():
    rng = np.random.default_rng(4)
    lanes = [
        np.array([[0, 0, 0], [30, 0, 0], [60, 5, 0]], F),
        np.array([[0, 3.5, 0], [60, 3.5, 0]], F),
        np.array([[30, -30, 0], [30, 30, 0], [30, 30, 0]], F),
    ]
    table = traffic_lights.build_lane_table(lanes, [1, 2, 3])
    xy = rng.uniform([-10, -35], [70, 35], (2000, 2)).astype(F)
    expected = traffic_lights.nearest_lane_segment(table, xy)
    seg = np.flatnonzero(table.valid)
    got = jitted(dense.nearest_lane_segment, xy, table.start[seg], table.delta[seg], np.ones(len(seg), bool))
    np.testing.assert_array_equal(seg[got], expected)


@pytest.mark.parametrize("shape", [(50, 4), (3, 20, 4)])
def test_box_geometry_under_jit(shape):
    rng = np.random.default_rng(5)
    n = int(np.prod(shape[:-1]))
    a = [v.reshape(shape[:-1]) for v in random_boxes(rng, n)]
    b = [v.reshape(shape[:-1]) for v in random_boxes(rng, n)]

    def distance(a, b):
        corners = []
        for x, y, length, width, heading in (a, b):
            s, c = sincos32(heading)
            corners.append(box_geometry.box_corners_xy(x, y, length, width, c, s))
        return box_geometry.origin_signed_distance(*box_geometry.minkowski_difference(*corners[0], *corners[1]))

    np.testing.assert_array_equal(jitted(distance, a, b), distance(a, b))


# --- NaN and inf, as the official code scores them ------------------------------------------------


def sequential_argmin(row):
    """TensorFlow's CPU argmin, one value at a time: strictly below the best so far, from float32's max."""
    best, index = F(np.finfo(F).max), 0
    for i, value in enumerate(row):
        if value < best:
            best, index = value, i
    return index


def test_strict_argmin_is_tensorflows():
    from wosac_eval.features.spatial import strict_argmin

    rng = np.random.default_rng(7)
    rows = rng.normal(size=(400, 9)).astype(F)
    draw = rng.random(rows.shape)
    rows[draw < 0.2] = np.nan
    rows[(draw > 0.2) & (draw < 0.3)] = np.inf
    rows[(draw > 0.3) & (draw < 0.33)] = -np.inf
    rows[0], rows[1], rows[2] = np.nan, np.inf, np.finfo(F).max
    rows[3, ::2] = 2.0  # ties
    want = [sequential_argmin(r) for r in rows]
    np.testing.assert_array_equal(strict_argmin(rows), want)
    np.testing.assert_array_equal(jitted(strict_argmin, rows), want)
    # Along another axis, and in one reduction with the value picked (the dense time to collision's).
    np.testing.assert_array_equal(jitted(lambda r: strict_argmin(r.T, axis=0), rows), want)
    pick, value = jitted(dense._strict_argmin_and_value, rows)
    np.testing.assert_array_equal(pick, want)
    np.testing.assert_array_equal(value, rows[np.arange(len(rows)), want])


def test_nearest_object_spreads_nan_as_the_all_pairs_minimum():
    rng = np.random.default_rng(8)
    objects, steps, evaluated = 14, 6, 5
    x, y, length, width, heading = (a.reshape(objects, steps) for a in random_boxes(rng, objects * steps))
    x[3, 1], y[9, 2], heading[0, 3], length[12, 4], x[1, 5] = np.nan, np.inf, np.nan, np.inf, -np.inf
    valid = rng.random((objects, steps)) < 0.85
    valid[[3, 9, 0, 12, 1], [1, 2, 3, 4, 5]] = True
    valid[5, 0] = False
    x[5, 0] = np.nan  # invalid: masked, spreads nothing
    with np.errstate(invalid="ignore", over="ignore"):
        sin_h, cos_h = sincos32(heading)
        got = interaction.distance_to_nearest_object(x, y, length, width, cos_h, sin_h, valid, evaluated)
        # The official definition: every pair, the self pair offset by 1e10, invalid pairs 1e10, min with NaN.
        radius = interaction.corner_radius(length, width)
        box = lambda i: (x[i], y[i], length[i] - 2 * radius[i], width[i] - 2 * radius[i], cos_h[i], sin_h[i], radius[i])
        want = np.empty((evaluated, steps), F)
        for e in range(evaluated):
            pairs = np.stack([interaction.rounded_box_distance(box(e), box(o)) for o in range(objects)])
            pairs[e] += interaction.EXTREMELY_LARGE_DISTANCE
            pairs = np.where(valid[e] & valid, pairs, interaction.EXTREMELY_LARGE_DISTANCE)
            want[e] = np.minimum(pairs.min(axis=0), interaction.EXTREMELY_LARGE_DISTANCE)
    assert np.isnan(want).any() and np.isfinite(want).any()
    np.testing.assert_array_equal(got, want)
    dense_got = jitted(
        lambda *a: dense.nearest_object_distance(*a, evaluated), x, y, length, width, cos_h, sin_h, valid
    )
    np.testing.assert_array_equal(dense_got, want)


def test_road_edge_of_a_non_finite_point_is_the_official_padding_pick():
    loop = np.array([[0, 0, 0], [40, 0, 0], [40, 30, 0], [0, 30, 0], [0, 0, 0]], F)
    short = np.array([[-10, -10, 0], [0, -15, 0], [10, -12, 0]], F)  # shorter: padding segments follow it
    table = road_edge.build_segment_table([loop, short])
    queries = np.array([[np.nan, 1, 0], [5, np.inf, 0], [-np.inf, 4, 0], [5, 5, np.nan], [5, 5, np.inf], [3, 4, 0]], F)
    got = road_edge.signed_distance_to_polylines(table, queries)
    # Officially every valid segment is then at NaN or inf, never picked: the first padding segment is
    # (at 1e10), and its signed distance is sign * 1e10, NaN where the sign is.
    from wosac_eval.features.spatial import non_finite_pick

    pick = non_finite_pick(table.valid)
    assert not table.valid[pick] and table.valid[:pick].all()
    with np.errstate(invalid="ignore"):
        rel_t, _, _ = road_edge.segment_distances(*queries.T, *table.start[pick], *table.delta[pick])
        side = lambda seg: road_edge.side_of_segment(
            queries[:, 0], queries[:, 1], *table.start[seg, :2], *table.delta[seg, :2]
        )
        sign = road_edge.corner_sign(
            rel_t,
            side(pick),
            side(table.prior[pick]),
            side(table.next[pick]),
            table.convex_before[pick],
            table.convex_after[pick],
            table.prior_valid[pick],
            table.next_valid[pick],
        )
    want = (sign * road_edge.EXTREMELY_LARGE_DISTANCE).astype(F)
    np.testing.assert_array_equal(got[:5], want[:5])
    assert np.isfinite(got[5]) and abs(got[5]) < 100
    segments = map_arrays.segment_table_arrays(table)
    np.testing.assert_array_equal(jitted(dense_road_edge.signed_distance_to_road_edge, queries, segments), got)


@pytest.mark.parametrize("challenge", ["sim_agents", "scenario_gen"])
@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_scene_features_with_nan_and_inf_equal_between_numpy_and_jax(challenge):
    from wosac_eval.features.metric_features import scenario_features
    from wosac_eval.sim import scenes
    from wosac_eval.sim.baselines import policy_rollouts
    from wosac_eval.arrays.scenario import scenario_arrays

    proto = scenes.generate_scenes(1, seed=5)[0]
    scenario = scenario_arrays(proto)
    rollouts = policy_rollouts(proto, "constant_velocity", seed=1, challenge=challenge)
    fields = {
        name: getattr(rollouts, name).copy()
        for name in ("x", "y", "z", "heading", "length", "height")
        if getattr(rollouts, name) is not None
    }
    fields["x"][0, 0, 20] = np.nan
    fields["y"][1, 2, 30] = -np.inf
    fields["heading"][2, 1, 40] = np.inf
    fields["z"][2, 0, 5] = np.nan
    if "height" in fields:
        fields["height"][1, 1, 50] = np.inf
        fields["length"][0, 3, 60] = np.nan
    rollouts = dataclasses.replace(rollouts, **fields)
    numpy_log, numpy_sim = scenario_features(scenario, rollouts, challenge=challenge)
    jax_log, jax_sim = jax_backend.scenario_features(scenario, rollouts, challenge=challenge)
    assert np.isnan(numpy_sim.distance_to_nearest_object).any() and np.isnan(numpy_sim.distance_to_road_edge).any()
    for name in (
        "linear_speed",
        "angular_speed",
        "distance_to_nearest_object",
        "collision_per_step",
        "time_to_collision",
        "distance_to_road_edge",
        "offroad_per_step",
        "traffic_light_violation_per_step",
        "average_displacement_error",
    ):
        np.testing.assert_array_equal(np.asarray(getattr(jax_sim, name)), getattr(numpy_sim, name), err_msg=name)


_SPEEDS_WITH_FUSION = """
import numpy as np, jax, jax.numpy as jnp
from wosac_eval.backends import jax_backend
from wosac_eval.features import kinematics
rng = np.random.default_rng(0)
x, y = ((rng.normal(size=(64, 91)).cumsum(-1) * 3 + offset).astype(np.float32) for offset in (1000, -500))
z = (rng.normal(size=(64, 91)) * 0.1).astype(np.float32)
heading = rng.uniform(-3, 3, size=(64, 91)).astype(np.float32)
want = kinematics.kinematic_features(x, y, z, heading, 0.1)
got = jax.jit(lambda *a: kinematics.kinematic_features(*a, 0.1))(x, y, z, heading)
differing = sum(int((~((np.asarray(g) == w) | np.isnan(w))).sum()) for g, w in zip(got, want))
d = [kinematics.central_difference(v) for v in (x, y, z)]
fused_sum = np.asarray(jax.jit(lambda a, b, c: a * a + b * b + c * c)(*d))
control = int((fused_sum != d[0] * d[0] + d[1] * d[1] + d[2] * d[2])[:, 1:-1].sum())
print(jax_backend.fma_contraction(), control, differing)
"""


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_speeds_stay_exact_where_xla_fuses_multiply_adds():
    """Without `exact_cpu()` XLA fuses `a * b + c` on a CPU with FMA (as on a GPU): the squares of a speed
    are still rounded one by one, so the kinematic features equal numpy's bit for bit."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    out = subprocess.run(
        [sys.executable, "-c", _SPEEDS_WITH_FUSION], env=env, capture_output=True, text=True, check=True
    )
    fused, control, differing = out.stdout.split()
    if fused != "True":
        pytest.skip("this CPU has no fused multiply-add: XLA cannot fuse here")
    assert int(control) > 0  # the plain sum of squares is fused here: the check is not vacuous
    assert int(differing) == 0


def test_float32_roots_and_quotients_go_through_float64_in_the_exact_mode():
    """XLA's float32 sqrt and division are not correctly rounded on every device (a GPU); under x64 they
    are computed in float64 and rounded once, which is exact, and equal numpy's bit for bit."""
    from wosac_eval.features import xp as xp_module

    rng = np.random.default_rng(3)
    # Normal numbers only: XLA's CPU flushes subnormal operands to zero, in float32 and float64 alike.
    special = [0.0, -0.0, 1.1754944e-38, 3e38, np.inf, -np.inf, np.nan, -1.0, 2.0, 0.1]
    a = np.concatenate([rng.uniform(0, 1e3, 5000), 10.0 ** rng.uniform(-18, 18, 5000), special]).astype(F)
    b = np.concatenate([rng.uniform(0.01, 10, 5000), 10.0 ** rng.uniform(-18, 18, 5000), special[::-1]]).astype(F)
    with jax.enable_x64(True):
        traced = str(jax.make_jaxpr(lambda u, v: (xp_module.sqrt(u, jnp), divide(u, v)))(a, b))
        got_sqrt, got_div = jitted(lambda u, v: (xp_module.sqrt(u, jnp), divide(u, v)), a, b)
        with xp_module.float32_precision():  # the float32 mode has no float64
            assert "f64" not in str(jax.make_jaxpr(lambda u, v: (xp_module.sqrt(u, jnp), divide(u, v)))(a, b))
    assert "f64" in traced
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        np.testing.assert_array_equal(got_sqrt, np.sqrt(a))
        np.testing.assert_array_equal(got_div, a / b)
    assert got_sqrt.dtype == got_div.dtype == F


@pytest.mark.skipif(jax_driver.memory_maps() is None, reason="no /proc/self/maps or vm.max_map_count here (not Linux)")
def test_compiled_programs_are_dropped_past_a_share_of_the_map_limit():
    # XLA's CPU programs hold memory mappings while cached; past the share, they are given back.
    programs = [jax.jit(lambda x, k=k: jnp.sin(x) * k + jnp.cumsum(x)) for k in range(8)]
    for f in programs:
        f(jnp.arange(64.0)).block_until_ready()
    held = jax_driver.memory_maps()[0]
    pending = programs[0](jnp.arange(64.0))
    assert not jax_driver.drop_programs_near_map_limit([pending], share=1.0)
    assert jax_driver.drop_programs_near_map_limit([pending], share=0.0)
    assert jax_driver.memory_maps()[0] < held
    np.testing.assert_array_equal(np.asarray(pending), np.asarray(programs[0](jnp.arange(64.0))))
