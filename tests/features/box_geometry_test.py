"""Tests of box corners and the sharp-cornered box-box signed distance.

Hand-built cases have answers derived on paper; random cases are checked
against two independent references: FCL (distance for separated pairs,
penetration depth for overlapping ones) and shapely's polygon distance.
"""

import math

import fcl
import numpy as np
import pytest
import shapely

from wosac_eval.features import box_geometry
from wosac_eval.features.float32_math import cos32, sin32

F = np.float32
EPS32 = float(np.finfo(F).eps)
SQRT_HALF = F(math.sqrt(0.5))


def corners(x, y, length, width, cos_h=1.0, sin_h=0.0):
    return box_geometry.box_corners_xy(*(np.asarray(v, F) for v in (x, y, length, width, cos_h, sin_h)))


def signed_distance(a, b):
    """Signed distance between two boxes given as (x, y, length, width, cos, sin)."""
    ax, ay = corners(*a)
    bx, by = corners(*b)
    return float(box_geometry.origin_signed_distance(*box_geometry.minkowski_difference(ax, ay, bx, by)))


def test_corners_axis_aligned():
    cx, cy = corners(1, 2, 4, 2)
    assert cx.dtype == F and cx.shape == (4,)
    # Front-left, rear-left, rear-right, front-right: counter-clockwise.
    np.testing.assert_array_equal(cx, [3, -1, -1, 3])
    np.testing.assert_array_equal(cy, [3, 3, 1, 1])


def test_corners_rotated_90_degrees():
    cx, cy = corners(1, 2, 4, 2, cos_h=0, sin_h=1)
    # Facing +y: the front-left corner is 2 m ahead (+y) and 1 m left (-x).
    np.testing.assert_array_equal(cx, [0, 0, 2, 2])
    np.testing.assert_array_equal(cy, [4, 0, 0, 4])


def test_corners_rotated_45_degrees():
    cx, cy = corners(0, 0, 2 * math.sqrt(2), 2 * math.sqrt(2), SQRT_HALF, SQRT_HALF)
    # A square of half-diagonal 2 turned 45 degrees: corners on the axes.
    np.testing.assert_allclose(cx, [0, -2, 0, 2], atol=4 * EPS32)
    np.testing.assert_allclose(cy, [2, 0, -2, 0], atol=4 * EPS32)


def test_corners_are_counter_clockwise_for_any_heading():
    heading = np.linspace(-math.pi, math.pi, 101).astype(F)
    n = heading.size
    cx, cy = box_geometry.box_corners_xy(
        np.full(n, 5, F), np.full(n, -3, F), np.full(n, 4.5, F), np.full(n, 1.8, F), cos32(heading), sin32(heading)
    )
    assert cx.shape == (n, 4)
    # Shoelace area: positive (counter-clockwise) and equal to length * width.
    area = 0.5 * np.sum(cx * np.roll(cy, -1, -1) - np.roll(cx, -1, -1) * cy, axis=-1)
    np.testing.assert_allclose(area, 4.5 * 1.8, rtol=1e-5)
    np.testing.assert_allclose(cx.mean(-1), 5, atol=1e-5)
    np.testing.assert_allclose(cy.mean(-1), -3, atol=1e-5)


def test_heading_cos_sin_uses_libm_on_the_trailing_partial_packet():
    heading = np.linspace(-3, 3, 3 * 7).astype(F).reshape(3, 7)  # 21 = 2 packets + 5
    cos_h, sin_h = box_geometry.heading_cos_sin(heading)
    flat_h, flat_s = heading.reshape(-1), sin_h.reshape(-1)
    np.testing.assert_array_equal(flat_s[16:], np.sin(flat_h[16:].astype(np.float64)).astype(F))
    np.testing.assert_array_equal(flat_s[:16], sin32(flat_h[:16]))
    np.testing.assert_array_equal(cos_h.reshape(-1)[16:], np.cos(flat_h[16:].astype(np.float64)).astype(F))
    # A step slice keeps the tail of the full tensor, not of the slice.
    _, sin_tail = box_geometry.heading_cos_sin(heading, slice(5, 7))
    np.testing.assert_array_equal(sin_tail, sin_h[:, 5:7])


BOX = (0, 0, 4, 2)  # 4 m x 2 m, axis aligned at the origin


@pytest.mark.parametrize(
    "other, expected",
    [
        ((10, 0, 4, 2), 6.0),  # separated along x: 10 - 2 - 2
        ((0, -7, 4, 2), 5.0),  # separated along y: 7 - 1 - 1
        ((4, 0, 4, 2), 0.0),  # touching end to end
        ((0, 2, 4, 2), 0.0),  # touching side to side
        ((3, 0, 4, 2), -1.0),  # overlapping: pushed back 1 m along x (2 m along y)
        ((1, 0, 4, 2), -2.0),  # deep overlap: 2 m sideways beats 3 m backwards
        ((0, 0, 4, 2), -2.0),  # identical boxes
        ((6, 5, 4, 2), math.hypot(2, 3)),  # corner to corner: (2, 1) to (4, 4)
    ],
    ids=["gap-x", "gap-y", "touch-x", "touch-y", "overlap-x", "overlap-y", "same", "corners"],
)
def test_axis_aligned_pairs(other, expected):
    assert signed_distance(BOX, other) == pytest.approx(expected, abs=4 * EPS32 * 10)
    # Symmetric in its arguments.
    assert signed_distance(other, BOX) == pytest.approx(expected, abs=4 * EPS32 * 10)


def test_nested_box():
    # A 2 m square inside a 10 m square, offset 1 m towards +x: it must move
    # 5 m (to x > 5) to get out, the shortest way.
    assert signed_distance((0, 0, 10, 10), (1, 0, 2, 2)) == -5.0
    assert signed_distance((1, 0, 2, 2), (0, 0, 10, 10)) == -5.0


def test_rotated_45_degrees_vertex_to_face():
    # A 2 m square turned 45 degrees, 5 m to the right of an upright 2 m square:
    # its left vertex is at 5 - sqrt(2), the other's right face at 1.
    d = signed_distance((0, 0, 2, 2), (5, 0, 2, 2, SQRT_HALF, SQRT_HALF))
    assert d == pytest.approx(5 - math.sqrt(2) - 1, abs=1e-6)


def test_rotated_45_degrees_overlap():
    # Same, but 2 m apart: the vertex pokes sqrt(2) - 1 into the face; pushing
    # back along x is the shortest way out (along the turned box's own axes
    # it is farther).
    d = signed_distance((0, 0, 2, 2), (2, 0, 2, 2, SQRT_HALF, SQRT_HALF))
    assert d == pytest.approx(2 - math.sqrt(2) - 1, abs=1e-6)


def test_batched_shapes():
    ax, ay = corners(np.zeros((2, 3)), np.zeros((2, 3)), np.full((2, 3), 4), np.full((2, 3), 2))
    bx, by = corners(np.arange(6).reshape(2, 3) + 10, np.zeros((2, 3)), np.full((2, 3), 4), np.full((2, 3), 2))
    mx, my = box_geometry.minkowski_difference(ax, ay, bx, by)
    assert mx.shape == my.shape == (2, 3, 8)
    d = box_geometry.origin_signed_distance(mx, my)
    assert d.shape == (2, 3) and d.dtype == F
    np.testing.assert_array_equal(d, np.arange(6).reshape(2, 3) + 6)


def test_minkowski_difference_is_convex_counter_clockwise():
    rng = np.random.default_rng(7)
    n = 500
    h = rng.uniform(-math.pi, math.pi, (2, n)).astype(F)
    ax, ay = box_geometry.box_corners_xy(
        *rng.uniform(-50, 50, (2, n)).astype(F), *rng.uniform(0.5, 10, (2, n)).astype(F), cos32(h[0]), sin32(h[0])
    )
    bx, by = box_geometry.box_corners_xy(
        *rng.uniform(-50, 50, (2, n)).astype(F), *rng.uniform(0.5, 10, (2, n)).astype(F), cos32(h[1]), sin32(h[1])
    )
    mx, my = box_geometry.minkowski_difference(ax, ay, bx, by)
    ex, ey = np.roll(mx, -1, -1) - mx, np.roll(my, -1, -1) - my
    turn = ex * np.roll(ey, -1, -1) - ey * np.roll(ex, -1, -1)
    # Every turn is a left turn (or straight, for parallel edges), up to float32 noise.
    assert np.all(turn >= -1e-3)
    # Its area is that of the Minkowski sum of the two rectangles.
    area = 0.5 * np.sum(mx * np.roll(my, -1, -1) - np.roll(mx, -1, -1) * my, axis=-1)
    assert np.all(area > 0)


# --- Independent references -------------------------------------------------------------------

_TALL = 1000.0  # FCL boxes are 3D: a tall extent keeps the vertical axis from ever being the
# shortest way out of an overlap, so the penetration is the planar one.


def _fcl_box(x, y, length, width, heading):
    c, s = math.cos(heading), math.sin(heading)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return fcl.CollisionObject(fcl.Box(length, width, _TALL), fcl.Transform(rotation, np.array([x, y, 0.0])))


def fcl_signed_distance(a, b):
    """Distance when apart; minus FCL's deepest contact penetration when overlapping."""
    oa, ob = _fcl_box(*a), _fcl_box(*b)
    result = fcl.CollisionResult()
    if fcl.collide(oa, ob, fcl.CollisionRequest(enable_contact=True, num_max_contacts=64), result):
        return -max(c.penetration_depth for c in result.contacts)
    return fcl.distance(oa, ob, fcl.DistanceRequest(), fcl.DistanceResult())


def sat_minimum_translation(a, b):
    """Minimum translation distance of two overlapping rectangles, float64, by the separating axis theorem."""

    def pts(x, y, length, width, heading):
        c, s = math.cos(heading), math.sin(heading)
        return np.array(
            [
                [x + c * u * length / 2 - s * v * width / 2, y + s * u * length / 2 + c * v * width / 2]
                for u, v in ((1, 1), (-1, 1), (-1, -1), (1, -1))
            ]
        )

    pa, pb = pts(*a), pts(*b)
    best = math.inf
    for poly in (pa, pb):
        for i in range(4):
            e = poly[(i + 1) % 4] - poly[i]
            n = np.array([e[1], -e[0]]) / math.hypot(*e)
            qa, qb = pa @ n, pb @ n
            best = min(best, qa.max() - qb.min(), qb.max() - qa.min())
    return best


@pytest.mark.parametrize(
    "b, depth",
    [
        ((3, 0, 4, 2, 0.0), 1.0),
        ((1, 0, 4, 2, 0.0), 2.0),
        ((2.5, 0.3, 4, 2, math.radians(30)), None),
        ((0.5, 0.2, 4, 2, math.radians(10)), None),
        ((0.0, 0.0, 1, 1, math.radians(45)), None),
    ],
)
def test_fcl_box_penetration_is_the_minimum_translation_distance(b, depth):
    # What FCL's box-box contact depth means, checked before relying on it:
    # its deepest contact equals the separating-axis minimum translation.
    a = (0.0, 0.0, 4.0, 2.0, 0.0)
    expected = sat_minimum_translation(a, b) if depth is None else depth
    assert -fcl_signed_distance(a, b) == pytest.approx(expected, abs=1e-12)


def _random_pairs(rng, n):
    """Oriented rectangle pairs from far apart to nested, sizes 0.2..30 m, centres within 100 m."""
    x, y = rng.uniform(-100, 100, (2, n))
    size = np.exp(rng.uniform(math.log(0.2), math.log(30), (4, n)))
    heading = rng.uniform(-math.pi, math.pi, (2, n))
    # Centre distance as a fraction of the sum of half diagonals: < ~0.5 is
    # mostly overlapping or nested, > 1 always separated.
    reach = (np.hypot(size[0], size[1]) + np.hypot(size[2], size[3])) / 2
    r = rng.uniform(0, 1.3, n) * reach
    r[: n // 10] = rng.uniform(0, 0.05, n // 10) * reach[: n // 10]  # concentric-ish, often nested
    bearing = rng.uniform(-math.pi, math.pi, n)
    bx, by = x + r * np.cos(bearing), y + r * np.sin(bearing)
    # Every input is rounded to float32 first, so both sides see the same boxes.
    f = lambda v: v.astype(F)
    return f(x), f(y), f(size[0]), f(size[1]), f(heading[0]), f(bx), f(by), f(size[2]), f(size[3]), f(heading[1])


def _kernel_signed_distance(x, y, l1, w1, h1, bx, by, l2, w2, h2):
    ax, ay = box_geometry.box_corners_xy(x, y, l1, w1, cos32(h1), sin32(h1))
    cx, cy = box_geometry.box_corners_xy(bx, by, l2, w2, cos32(h2), sin32(h2))
    d = box_geometry.origin_signed_distance(*box_geometry.minkowski_difference(ax, ay, cx, cy))
    scale = np.abs(np.concatenate([ax, ay, cx, cy], axis=-1)).max(axis=-1)
    return d.astype(np.float64), scale


def _tolerance(scale):
    # Corners carry float32 rounding of magnitude eps * |coordinate| per
    # operation; the Minkowski sums, edge normalisation and projections add a
    # few more such roundings. Four eps of the largest coordinate bounds them
    # all (measured worst case ~0.9 eps over 10^4 random pairs). At 100 m this is 5e-5 m.
    return 4 * EPS32 * np.maximum(scale, 1.0)


def test_signed_distance_against_fcl_on_random_pairs():
    rng = np.random.default_rng(20251121)
    pairs = _random_pairs(rng, 2000)
    ours, scale = _kernel_signed_distance(*pairs)
    reference = np.array(
        [
            fcl_signed_distance(
                (float(p[0]), float(p[1]), float(p[2]), float(p[3]), float(p[4])),
                (float(p[5]), float(p[6]), float(p[7]), float(p[8]), float(p[9])),
            )
            for p in zip(*pairs)
        ]
    )
    overlapping = reference < 0
    # The draw covers both regimes generously.
    assert 400 < overlapping.sum() < 1600
    error = np.abs(ours - reference)
    worst = np.argmax(error / _tolerance(scale))
    assert np.all(error <= _tolerance(scale)), (
        f"pair {worst}: ours {ours[worst]}, FCL {reference[worst]}, inputs {[p[worst] for p in pairs]}"
    )
    # Signs agree wherever the reference is clear of float32 noise.
    clear = np.abs(reference) > _tolerance(scale)
    np.testing.assert_array_equal(np.sign(ours[clear]), np.sign(reference[clear]))


def test_nested_pairs_against_fcl():
    rng = np.random.default_rng(5)
    n = 300
    big = rng.uniform(8, 30, (2, n))
    small = rng.uniform(0.2, 2, (2, n))
    x, y = rng.uniform(-100, 100, (2, n))
    heading = rng.uniform(-math.pi, math.pi, (2, n))
    # Inner centre within a quarter of the outer box: always strictly inside.
    ox, oy = rng.uniform(-0.25, 0.25, (2, n)) * (big - 2 * 2)
    c, s = np.cos(heading[0]), np.sin(heading[0])
    bx, by = x + c * ox - s * oy, y + s * ox + c * oy
    pairs = tuple(v.astype(F) for v in (x, y, big[0], big[1], heading[0], bx, by, small[0], small[1], heading[1]))
    ours, scale = _kernel_signed_distance(*pairs)
    reference = np.array([fcl_signed_distance(tuple(map(float, p[:5])), tuple(map(float, p[5:]))) for p in zip(*pairs)])
    assert np.all(reference < -1)  # nested: deep penetration
    assert np.all(np.abs(ours - reference) <= _tolerance(scale))


def test_touching_pairs_against_fcl():
    # Boxes placed face to face at float32-exact positions, in each of the
    # four right-angle orientations: distance 0 up to float32 noise.
    rng = np.random.default_rng(11)
    n = 200
    length, width = (rng.integers(2, 40, (2, n)) / 4).astype(F)
    other_length, other_width = (rng.integers(2, 40, (2, n)) / 4).astype(F)
    x, y = (rng.integers(-400, 400, (2, n)) / 4).astype(F)
    turn = rng.integers(0, 4, n)
    cos_h, sin_h = np.array([1, 0, -1, 0], F)[turn], np.array([0, 1, 0, -1], F)[turn]
    slide = (rng.integers(-4, 5, n) / 4).astype(F)
    # The other box is axis-aligned, touching the first one's +x extent.
    half_extent_x = np.where(turn % 2 == 0, length, width) / 2
    bx = x + half_extent_x + other_length / 2
    by = y + slide
    ax, ay = box_geometry.box_corners_xy(x, y, length, width, cos_h, sin_h)
    cx, cy = box_geometry.box_corners_xy(bx, by, other_length, other_width, np.ones(n, F), np.zeros(n, F))
    ours = box_geometry.origin_signed_distance(*box_geometry.minkowski_difference(ax, ay, cx, cy))
    scale = np.abs(np.concatenate([ax, ay, cx, cy], -1)).max(-1)
    np.testing.assert_array_less(np.abs(ours), _tolerance(scale))
    for k in range(0, n, 20):
        ref = fcl_signed_distance(
            (float(x[k]), float(y[k]), float(length[k]), float(width[k]), turn[k] * math.pi / 2),
            (float(bx[k]), float(by[k]), float(other_length[k]), float(other_width[k]), 0.0),
        )
        assert abs(ref) < 1e-9


def test_right_angle_headings_against_fcl():
    # Headings that are multiples of 90 degrees give two equally low corners,
    # the tie case of the Minkowski vertex ordering: every pair of the four
    # orientations, at offsets from nested to apart.
    rng = np.random.default_rng(13)
    quarter = np.array([1, 0, -1, 0], F), np.array([0, 1, 0, -1], F)
    pairs = []
    for turn_a in range(4):
        for turn_b in range(4):
            for _ in range(12):
                a = (*rng.uniform(-50, 50, 2), *rng.uniform(0.5, 8, 2))
                b = (a[0] + rng.uniform(-8, 8), a[1] + rng.uniform(-8, 8), *rng.uniform(0.5, 8, 2))
                pairs.append((np.array(a, F), turn_a, np.array(b, F), turn_b))
    for a, turn_a, b, turn_b in pairs:
        ax, ay = box_geometry.box_corners_xy(*a, quarter[0][turn_a], quarter[1][turn_a])
        bx, by = box_geometry.box_corners_xy(*b, quarter[0][turn_b], quarter[1][turn_b])
        ours = float(box_geometry.origin_signed_distance(*box_geometry.minkowski_difference(ax, ay, bx, by)))
        reference = fcl_signed_distance((*map(float, a), turn_a * math.pi / 2), (*map(float, b), turn_b * math.pi / 2))
        scale = float(np.abs(np.concatenate([ax, ay, bx, by])).max())
        assert abs(ours - reference) <= _tolerance(scale), (a, turn_a, b, turn_b, ours, reference)


def test_separated_pairs_against_shapely():
    rng = np.random.default_rng(99)
    pairs = _random_pairs(rng, 1500)
    ours, scale = _kernel_signed_distance(*pairs)
    x, y, l1, w1, h1, bx, by, l2, w2, h2 = (p.astype(np.float64) for p in pairs)

    def polygons(x, y, length, width, heading):
        c, s = np.cos(heading), np.sin(heading)
        u = np.array([1, -1, -1, 1])[:, None] * length / 2
        v = np.array([1, 1, -1, -1])[:, None] * width / 2
        px, py = x + c * u - s * v, y + s * u + c * v
        return shapely.polygons(np.stack([px.T, py.T], axis=-1))

    pa, pb = polygons(x, y, l1, w1, h1), polygons(bx, by, l2, w2, h2)
    separated = ~shapely.intersects(pa, pb)
    assert separated.sum() > 300
    reference = shapely.distance(pa, pb)
    error = np.abs(ours - reference)[separated]
    assert np.all(error <= _tolerance(scale)[separated])
    # Where shapely sees an overlap, so does the kernel (up to float32 noise at contact).
    assert np.all(ours[~separated] <= _tolerance(scale)[~separated])
