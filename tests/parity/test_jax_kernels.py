"""The dense JAX drivers (features/dense.py) and the kernels under `jax.jit` against numpy, on random inputs.

Random inputs reach corners the scenario data may miss: huge angles, the
libm tail, degenerate segments, points past segment ends, ties.
"""
import numpy as np
import pytest

# First: restricts XLA's CPU code (no fused multiply-add) before JAX starts.
from wosac_eval.backends import jax_backend  # noqa: F401

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from wosac_eval.features import box_geometry, dense, interaction, road_edge, traffic_lights  # noqa: E402
from wosac_eval.features.float32_math import fma32, sincos32  # noqa: E402
from wosac_eval.features.xp import array_namespace, divide  # noqa: E402

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
    x = np.concatenate([rng.normal(0, 4, 4000), rng.uniform(-1e5, 1e5, 1000),
                        [0.0, -0.0, 25966.0, 18838.0, 1e30, np.inf, -np.inf, np.nan]]).astype(F)
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


def test_time_to_collision_dense_equals_numpy():
    rng = np.random.default_rng(2)
    objects, steps, evaluated = 10, 9, 4
    # A convoy along x with jitter, so that many pairs follow each other.
    x = (np.arange(objects)[:, None] * 7.0 + np.arange(steps)[None] * rng.uniform(0.5, 2, (objects, 1))
         + rng.normal(0, 0.3, (objects, steps))).astype(F)
    y = rng.normal(0, 1.0, (objects, steps)).astype(F)
    heading = rng.normal(0, 0.2, (objects, steps)).astype(F)
    length, width = np.full((objects, steps), F(4.5)), np.full((objects, steps), F(2.0))
    valid = rng.random((objects, steps)) < 0.9
    steps_eval = slice(1, steps)
    expected = interaction.time_to_collision(x, y, length, width, heading, valid, evaluated, 0.1, steps_eval)
    assert (expected < interaction.MAXIMUM_TIME_TO_COLLISION).any()
    from wosac_eval.features.float32_math import packet_tail
    from wosac_eval.features.kinematics import linear_speed
    speed = linear_speed(x, y, np.zeros_like(x), 0.1)
    step_major = lambda a: np.ascontiguousarray(a[:, steps_eval].T)
    ego_tail = packet_tail((steps, evaluated, 1))[steps_eval]
    pair_tail = packet_tail((steps, evaluated, objects))[steps_eval]
    got = jitted(lambda *a: dense.time_to_collision(*a, num_evaluated=evaluated),
                 *map(step_major, (x, y, length, width, heading, speed, valid)), ego_tail, pair_tail)
    np.testing.assert_array_equal(got.T, expected)


def test_road_edge_dense_equals_numpy():
    rng = np.random.default_rng(3)
    # A closed loop, an open zig-zag with a repeated point (degenerate segment) and a ramp.
    loop = np.array([[0, 0, 0], [40, 0, 0], [40, 30, 0], [0, 30, 0], [0, 0, 0]], F)
    zigzag = np.array([[-10, -10, 0], [0, -15, 0], [0, -15, 0], [10, -10, 0], [20, -18, 1]], F)
    ramp = np.array([[50, -5, 0], [50, 40, 12]], F)
    table = road_edge.build_segment_table([loop, zigzag, ramp])
    queries = np.concatenate([rng.uniform([-20, -30, -1], [60, 50, 8], (3000, 3)),
                              loop[:4] + F(0.0), [[45, 30, 0], [-3, -4, 0]]]).astype(F)
    expected = road_edge.signed_distance_to_polylines(table, queries)
    segments = jax_backend._segment_arrays(table)
    got = jitted(dense.signed_distance_to_road_edge, queries, segments)
    np.testing.assert_array_equal(got, expected)
    # Padded segments and a small chunk (several lax.map steps) change nothing.
    padded = {k: jax_backend._pad_axis(v, 64, 0) for k, v in segments.items()}
    old = dense.PAIRS_PER_CHUNK
    dense.PAIRS_PER_CHUNK = 64 * 100
    try:
        np.testing.assert_array_equal(jitted(dense.signed_distance_to_road_edge, queries, padded), expected)
    finally:
        dense.PAIRS_PER_CHUNK = old


def test_lane_search_dense_equals_numpy():
    rng = np.random.default_rng(4)
    lanes = [np.array([[0, 0, 0], [30, 0, 0], [60, 5, 0]], F), np.array([[0, 3.5, 0], [60, 3.5, 0]], F),
             np.array([[30, -30, 0], [30, 30, 0], [30, 30, 0]], F)]
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
