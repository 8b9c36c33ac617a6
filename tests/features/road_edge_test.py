"""Tests of the signed distance to road edges on hand-built maps and against brute force."""

import math

import numpy as np
import pytest

from wosac_eval.features import road_edge
from wosac_eval.features.box_geometry import box_bottom_corners
from wosac_eval.features.road_edge import pruned_search, signed_distance

F = np.float32


def polyline(*points, z=0.0):
    p = np.array(points, np.float64)
    if p.shape[1] == 2:
        p = np.concatenate([p, np.full((len(p), 1), z)], axis=1)
    return p.astype(F)


def distances(table, *points):
    q = np.array([p if len(p) == 3 else (*p, 0.0) for p in points], F)
    return road_edge.signed_distance_to_polylines(table, q)


# A 100 m square road, counter-clockwise: the road is on the left, i.e. inside.
SQUARE = polyline((0, 0), (100, 0), (100, 100), (0, 100), (0, 0))


@pytest.fixture(scope="module")
def square():
    return road_edge.build_segment_table([SQUARE])


def test_square_inside_and_outside(square):
    d = distances(square, (10, 50), (-5, 50), (50, 97), (50, 130), (3, 4), (50, 0))
    assert d.dtype == F
    np.testing.assert_array_equal(d, [-10, 5, -3, 30, -3, 0])


def test_square_outside_a_convex_corner(square):
    # Beyond the corner (0, 0) the nearest point is the corner itself, 5 m away,
    # and the point is off the road although it is "left" of one of the two sides' lines.
    np.testing.assert_array_equal(distances(square, (-3, -4), (-4, -3), (103, 104), (-3, 104)), 5)


def test_square_is_cyclic_and_closed(square):
    assert square.valid.sum() == 4
    # Each segment's neighbours wrap around the loop.
    np.testing.assert_array_equal(square.prior, [3, 0, 1, 2])
    np.testing.assert_array_equal(square.next, [1, 2, 3, 0])
    assert square.convex_before.all() and square.convex_after.all()


# An L-shaped road, counter-clockwise, with a reflex corner at (10, 10).
L_SHAPE = polyline((0, 0), (20, 0), (20, 10), (10, 10), (10, 20), (0, 20), (0, 0))


def test_concave_corner():
    table = road_edge.build_segment_table([L_SHAPE])
    d = distances(table, (8, 8), (12, 12), (11, 11), (5, 5))
    # (8, 8): on the road, nearest to the reflex corner at distance sqrt(8).
    # (12, 12) and (11, 11): in the notch, off the road, 2 m and 1 m from the two sides.
    np.testing.assert_allclose(d, [-math.sqrt(8), 2, 1, -5], rtol=1e-7)


def test_straight_non_cyclic_edge():
    table = road_edge.build_segment_table([polyline((0, 0), (10, 0))])
    d = distances(table, (5, 3), (5, -3), (13, 4), (13, -4), (-3, 4), (-3, -4))
    # Past the ends the distance is to the end point and the side is that of the segment's line.
    np.testing.assert_array_equal(d, [-3, 3, -5, 5, -5, 5])


def test_open_polyline_convex_turn():
    table = road_edge.build_segment_table([polyline((0, 0), (10, 0), (10, 10))])
    # Outside the left turn at (10, 0): off the road.
    np.testing.assert_allclose(distances(table, (12, -2), (8, 2)), [math.sqrt(8), -2], rtol=1e-7)
    # A non-cyclic polyline's ends are their own neighbours.
    np.testing.assert_array_equal(table.prior, [0, 0])
    np.testing.assert_array_equal(table.next, [1, 1])


def test_z_stretch_picks_the_edge_at_the_right_height():
    # Two parallel edges 2 m apart in the plane but 10 m apart in height:
    # the lower one runs +x (road at y > 0), the upper one runs -x (road at y < 2).
    lower = polyline((0, 0), (10, 0), z=0.0)
    upper = polyline((10, 2), (0, 2), z=10.0)
    table = road_edge.build_segment_table([lower, upper])
    d = distances(table, (5, 1.5, 0.0), (5, 1.5, 10.0), (5, -1.0, 0.0), (5, 3.0, 9.0))
    # Planar distances: 1.5 to the lower edge, 0.5 to the upper one.
    np.testing.assert_array_equal(d, [-1.5, -0.5, 1.0, 1.0])


def test_height_difference_is_stretched_threefold():
    # A point 1 m above the plane of edge A, which is 3.1 m away in the plane,
    # and level with edge B 3.2 m away on the other side: stretched, A is
    # sqrt(3.1^2 + 3^2) = 4.31 m away, B 3.2 m, so B is picked.
    a = polyline((-10, -3.1), (10, -3.1), z=0.0)  # runs +x: the point (y = 0) is on its road side
    b = polyline((10, 3.2), (-10, 3.2), z=1.0)  # runs -x: the point is on its road side too
    table = road_edge.build_segment_table([a, b])
    np.testing.assert_allclose(distances(table, (0, 0, 1.0)), [-3.2], rtol=1e-7)
    # Without the height difference A would win.
    np.testing.assert_allclose(distances(table, (0, 0, 0.5)), [-3.1], rtol=1e-7)


def test_short_polylines_are_ignored(square):
    with_short = road_edge.build_segment_table([polyline((50, 50)), SQUARE, np.zeros((0, 3), F)])
    queries = [(50, 50), (10, 50), (-5, 50)]
    np.testing.assert_array_equal(distances(with_short, *queries), distances(square, *queries))


def test_no_road_edges_is_an_error():
    with pytest.raises(ValueError, match="no road edges"):
        road_edge.build_segment_table([polyline((1, 1))])


def test_padding_of_shorter_polylines():
    table = road_edge.build_segment_table([polyline((0, 0), (10, 0)), SQUARE])
    # The first polyline is padded to the square's 5 points: 4 segments, 1 valid.
    assert table.start.shape == (8, 3)
    np.testing.assert_array_equal(table.valid, [True, False, False, False, True, True, True, True])
    np.testing.assert_array_equal(distances(table, (5, -1)), [1])


def boxes_distance(table, x, y, length, width, heading, valid=None, z=0.0):
    x, y, length, width, heading = (np.atleast_2d(np.asarray(v, F)) for v in (x, y, length, width, heading))
    if valid is None:
        valid = np.ones(x.shape, bool)
    return road_edge.box_distance_to_road_edge(
        x,
        y,
        np.full(x.shape, z, F),
        length,
        width,
        np.cos(heading).astype(F),
        np.sin(heading).astype(F),
        np.asarray(valid, bool),
        table,
    )


def test_box_distance_is_the_most_off_road_corner(square):
    # One object over three steps: inside (20 m from x = 0, corners 2 m closer),
    # straddling the edge, outside.
    d = boxes_distance(square, [[20, 1, -10]], [[50, 50, 50]], [[4, 4, 4]], [[2, 2, 2]], [[0, 0, 0]])
    assert d.shape == (1, 3) and d.dtype == F
    np.testing.assert_array_equal(d, [[-18, 1, 12]])
    assert np.array_equal(d > road_edge.OFFROAD_DISTANCE_THRESHOLD, [[False, True, True]])


def test_box_distance_turned_box(square):
    # A 4 x 2 box turned 90 degrees 10 m from the bottom side: its rear corners are 8 m from it.
    d = boxes_distance(square, [[50]], [[10]], [[4]], [[2]], [[math.pi / 2]])
    np.testing.assert_allclose(d, [[-8]], atol=1e-5)


def test_box_distance_invalid_is_large_negative(square):
    d = boxes_distance(square, [[-10, -10]], [[50, 50]], [[4, 4]], [[2, 2]], [[0, 0]], valid=[[True, False]])
    assert d[0, 0] == 12
    assert d[0, 1] == -road_edge.EXTREMELY_LARGE_DISTANCE


# --- Brute force ---------------------------------------------------------------------------------


@pytest.fixture(params=["cell lists", "ring searches"])
def strategy(request, monkeypatch):
    """Each brute-force test runs with each of the search's two ways forced: every query through its
    cell's candidate list, and every query by its own ring search (what scattered queries get)."""
    limit = 0.0 if request.param == "cell lists" else math.inf
    monkeypatch.setattr(pruned_search, "SPARSE_QUERIES_PER_CELL", limit)
    return request.param


def brute_force(table, queries):
    """Signed distance with every valid segment evaluated, same float32 operations."""
    q = np.asarray(queries, F)[:, None, :]
    idx = np.flatnonzero(table.valid)
    start, delta = table.start[idx][None], table.delta[idx][None]
    to_point = q - start
    along = to_point[..., 0] * delta[..., 0] + to_point[..., 1] * delta[..., 1]
    squared = delta[..., 0] * delta[..., 0] + delta[..., 1] * delta[..., 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        rel_t = np.where(squared == 0, F(0), along / squared)
    clipped = np.clip(rel_t, F(0), F(1))
    offset = to_point - delta * clipped[..., None]
    oz = offset[..., 2] * F(3)
    d3 = np.sqrt(offset[..., 0] * offset[..., 0] + offset[..., 1] * offset[..., 1] + oz * oz)
    d2 = np.sqrt(offset[..., 0] * offset[..., 0] + offset[..., 1] * offset[..., 1])
    best = np.argmin(d3, axis=1)  # first minimum: ties go to the lowest segment index
    rows = np.arange(len(q))
    seg, t, dist = idx[best], rel_t[rows, best], d2[rows, best]
    xy = q[:, 0, :2]

    def side(s):
        sx, sy = xy[:, 0] - table.start[s, 0], xy[:, 1] - table.start[s, 1]
        return np.sign(sx * table.delta[s, 1] - sy * table.delta[s, 0])

    n, n_prior, n_next = side(seg), side(table.prior[seg]), side(table.next[seg])
    sign = n.copy()
    before = (t < 0) & table.prior_valid[seg]
    after = (t > 1) & table.next_valid[seg]
    sign[before] = np.where(table.convex_before[seg], np.maximum(n, n_prior), np.minimum(n, n_prior))[before]
    sign[after] = np.where(table.convex_after[seg], np.maximum(n, n_next), np.minimum(n, n_next))[after]
    return (sign * dist).astype(F)


def assert_equals_brute_force(table, queries):
    """The search's signed distances equal `brute_force`'s bit for bit, naming the first query that differs."""
    ours = road_edge.signed_distance_to_polylines(table, queries)
    reference = brute_force(table, queries)
    mismatch = np.flatnonzero(ours != reference)
    assert mismatch.size == 0, (
        f"{mismatch.size} mismatches, e.g. query {queries[mismatch[0]]}: "
        f"{ours[mismatch[0]]} vs {reference[mismatch[0]]}"
    )


def random_map(rng):
    polylines = []
    for k in range(40):
        n = int(rng.integers(2, 40))
        step = np.exp(rng.uniform(math.log(0.05), math.log(30), n))  # 5 cm to 30 m segments
        angle = np.cumsum(rng.normal(0, 0.6, n))
        xy = rng.uniform(-150, 150, 2) + np.cumsum(np.stack([step * np.cos(angle), step * np.sin(angle)], 1), 0)
        level = rng.choice([0.0, 0.0, 6.0, 12.0])
        z = level + np.cumsum(rng.normal(0, 0.05, n))
        p = np.concatenate([xy, z[:, None]], 1)
        if k % 5 == 0:
            p = np.concatenate([p, p[:1]])  # closed loop
        if k % 7 == 0:
            p = np.concatenate([p[:3], p[2:3], p[3:]])  # a zero-length segment
        polylines.append(p.astype(F))
    # A dense ring: from its centre hundreds of segments are equally near (long candidate lists,
    # ties decided by the lowest index).
    t = np.linspace(0, 2 * math.pi, 400)
    polylines.append(np.stack([400 + 5 * np.cos(t), 400 + 5 * np.sin(t), np.zeros_like(t)], 1).astype(F))
    return polylines


def test_candidate_search_equals_brute_force(strategy):
    rng = np.random.default_rng(1234)
    polylines = random_map(rng)
    table = road_edge.build_segment_table(polylines)
    queries = np.concatenate(
        [
            np.stack([rng.uniform(-250, 250, 3000), rng.uniform(-250, 250, 3000), rng.uniform(-2, 14, 3000)], 1),
            # Far away from everything.
            np.array([[2000, 2000, 0], [-3000, 100, 50]]),
            # Exactly on vertices, and at the ring centre and near it.
            np.concatenate(polylines)[::7],
            np.array([[400, 400, 0], [400.3, 399.8, 0.1], [400, 400, 5]]),
        ]
    ).astype(F)
    assert_equals_brute_force(table, queries)


def test_hand_cases_equal_brute_force(square, strategy):
    table = road_edge.build_segment_table([L_SHAPE, SQUARE, polyline((0, 0), (10, 0), (10, 10))])
    q = np.array([(8, 8, 0), (12, 12, 0), (-3, -4, 0), (12, -2, 0), (50, 50, 0), (10, 10, 0)], F)
    np.testing.assert_array_equal(road_edge.signed_distance_to_polylines(table, q), brute_force(table, q))


def steep_ramps():
    """Ramps of short segments climbing up to 2 m per metre, side by side at different heights.

    On a steep segment the planar projection slides along the slope as the point
    moves, so the selection distance changes faster than the point itself: a
    search bound that assumes distances change at most 1:1 misses the nearest
    segment here.
    """
    x = np.arange(0, 20, 0.5, dtype=F)
    ramps = []
    for k, slope in enumerate((0.5, 1.0, 2.0)):
        for side in (0.0, 1.5):
            y = np.full_like(x, 3.0 * k + side)
            ramps.append(np.stack([x, y, slope * x + 0.7 * k], 1))
            ramps.append(np.stack([x[::-1], y[::-1] + 0.4, slope * x[::-1] + 0.7 * k + 1.0], 1))
    return ramps


def test_steep_ramps_equal_brute_force(strategy):
    rng = np.random.default_rng(7)
    table = road_edge.build_segment_table(steep_ramps())
    n = 20000
    queries = np.stack([rng.uniform(-2, 22, n), rng.uniform(-2, 11, n), rng.uniform(-2, 42, n)], 1).astype(F)
    assert_equals_brute_force(table, queries)


def test_far_placeholder_queries_equal_brute_force(strategy):
    """A map kilometres from the origin, with boxes at placeholder states (the origin, and 50 m up).

    The few far queries are grouped apart from those near the map (`_cells_of`'s core box);
    results still equal the all-pairs search.
    """
    rng = np.random.default_rng(11)
    offset = np.array([-7800.0, -6700.0, -180.0])
    polylines = [(p + offset).astype(F) for p in random_map(rng)]
    table = road_edge.build_segment_table(polylines)
    near = np.stack([rng.uniform(-200, 200, 4000), rng.uniform(-200, 200, 4000), rng.uniform(-3, 15, 4000)], 1)
    far = np.concatenate([np.zeros((40, 3)), np.tile([[0.0, 0.0, 50.0], [-7800.0, -6700.0, 400.0]], (5, 1))])
    queries = np.concatenate([near + offset, far, near[:50] + offset + [0, 0, 500]]).astype(F)
    assert_equals_brute_force(table, queries)


@pytest.mark.parametrize("hint_stride", [1, 2, 4, 7])
def test_hints_never_change_the_answer(hint_stride, strategy):
    """Each query first tries the answer of the query `hint_stride` before it: a hint from anywhere (a
    far query, a tie with a higher index, a segment on another level) leaves every answer exact."""
    rng = np.random.default_rng(5)
    polylines = random_map(rng)
    table = road_edge.build_segment_table(polylines)
    ring_centre = np.array([[400, 400, 0]] * 5 + [[400.0, 400.0, 1e-3], [400.0, 400.0, -1e-3]])
    walk = np.cumsum(rng.normal(0, 0.8, (3000, 3)) * [1, 1, 0.2], axis=0) + [0, 0, 6]
    queries = np.concatenate(
        [ring_centre, walk, ring_centre[::-1], rng.uniform(-250, 250, (500, 3)), np.concatenate(polylines)[::3]]
    ).astype(F)
    reference = brute_force(table, queries)
    segments = road_edge.nearest_segments(table, queries, hint_stride=hint_stride)
    assert np.array_equal(segments, road_edge.nearest_segments(table, queries, hint_stride=len(queries)))
    ours = signed_distance.signed_distance_to_segments(table, queries, segments)
    mismatch = np.flatnonzero(ours != reference)
    assert mismatch.size == 0, f"query {queries[mismatch[0]]}: {ours[mismatch[0]]} vs {reference[mismatch[0]]}"


def test_scattered_queries_search_their_rings_and_dense_ones_share_cell_lists():
    """By default a call's queries go through cell lists when many share a cell (a box's corners along its
    trajectories) and each by its own ring search when they are scattered (one vehicle every 50 m): either
    way the answers of the all-pairs search."""
    rng = np.random.default_rng(3)
    table = road_edge.build_segment_table(random_map(rng))
    scattered = np.stack([rng.uniform(-150, 150, 300), rng.uniform(-150, 150, 300), rng.uniform(-1, 13, 300)], 1)
    walk = np.cumsum(rng.normal(0, 0.05, (6000, 3)) * [1, 1, 0.1], axis=0) + [20, 20, 6]
    for queries, lists_built in ((scattered.astype(F), False), (walk.astype(F), True)):
        counts = {}
        segments = road_edge.nearest_segments(table, queries, counts)
        assert (counts["cells"] > 0) == lists_built, counts
        ours = signed_distance.signed_distance_to_segments(table, queries, segments)
        np.testing.assert_array_equal(ours, brute_force(table, queries))


def test_box_trajectories_equal_brute_force(strategy):
    """`box_distance_to_road_edge` over samples x objects x steps of boxes driving through the map (the
    order it searches in, a box's answer the hint of the next) equals the all-pairs search of their
    corners."""
    rng = np.random.default_rng(9)
    table = road_edge.build_segment_table(random_map(rng))
    samples, objects, steps = 3, 6, 40
    start = rng.uniform(-150, 150, (1, objects, 1, 2)) + rng.normal(0, 0.5, (samples, objects, 1, 2))
    heading = rng.uniform(-math.pi, math.pi, (samples, objects, 1)) + np.cumsum(
        rng.normal(0, 0.05, (samples, objects, steps)), axis=-1
    )
    centre = (start + np.cumsum(1.2 * np.stack([np.cos(heading), np.sin(heading)], -1), axis=2)).astype(F)
    boxes = (
        centre[..., 0],
        centre[..., 1],
        (rng.choice([0.0, 6.0], (samples, objects, 1)) + np.zeros(heading.shape)).astype(F),  # bottom
        np.full(heading.shape, 4.8, F),
        np.full(heading.shape, 2.0, F),
        np.cos(heading).astype(F),
        np.sin(heading).astype(F),
    )
    valid = rng.random((samples, objects, steps)) > 0.1
    ours = road_edge.box_distance_to_road_edge(*boxes, valid, table)
    corners = box_bottom_corners(*boxes)
    reference = brute_force(table, corners.reshape(-1, 3)).reshape(corners.shape[:-1]).max(axis=-1)
    np.testing.assert_array_equal(ours[valid], reference[valid])
    assert (ours[~valid] == -road_edge.EXTREMELY_LARGE_DISTANCE).all()


def test_boxes_of_every_kind_equal_their_corners_one_by_one():
    """`box_distance_to_road_edge` (corners computed in the search loop, boxes in its order) equals the
    most off-road of `signed_distance_to_polylines` of each corner of `box_bottom_corners` searched on
    its own, bit for bit: boxes on and off the map, on another level, invalid, NaN, and with two
    leading axes."""
    from wosac_eval.features.float32_math import sincos32

    rng = np.random.default_rng(12)
    table = road_edge.build_segment_table(random_map(rng))
    shape = (2, 3, 5, 17)
    x, y = (rng.uniform(-200, 200, shape).astype(F) for _ in range(2))
    x[0, 0, 0, :3] = [np.nan, np.inf, 5e6]
    bottom = rng.choice([0.0, 6.0, np.nan], shape, p=[0.6, 0.38, 0.02]).astype(F)
    length, width = rng.uniform(0.5, 6, shape).astype(F), rng.uniform(0.5, 3, shape).astype(F)
    sin_h, cos_h = sincos32(rng.uniform(-4, 4, shape).astype(F))
    valid = rng.random(shape) > 0.2
    ours = road_edge.box_distance_to_road_edge(x, y, bottom, length, width, cos_h, sin_h, valid, table)
    corners = box_bottom_corners(x, y, bottom, length, width, cos_h, sin_h)
    with np.errstate(invalid="ignore"):
        each = road_edge.signed_distance_to_polylines(table, corners.reshape(-1, 3))
    reference = each.reshape(corners.shape[:-1]).max(axis=-1)
    assert ours.shape == shape and ours.dtype == F
    np.testing.assert_array_equal(ours[valid].view(np.int32), reference[valid].view(np.int32))
    assert (ours[~valid] == -road_edge.EXTREMELY_LARGE_DISTANCE).all()


# --- Cell candidate tables (the fixed-shape search on a device) -------------------------------------


def planar_distances(points, start, delta):
    """float64 `(num_points, num_segments)` planar distance from each point to each segment."""
    s, d = start[:, :2].astype(np.float64), delta[:, :2].astype(np.float64)
    to_point = points[:, None, :] - s[None]
    squared = (d * d).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip(np.where(squared > 0, (to_point * d).sum(axis=2) / squared, 0.0), 0.0, 1.0)
    offset = to_point - d * t[..., None]
    return np.hypot(offset[..., 0], offset[..., 1])


@pytest.mark.parametrize("k", [1, 8, road_edge.CELL_CANDIDATES])
@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_cell_tables_list_the_nearest_and_bound_the_rest(k):
    """Every cell lists the k segments nearest its centre (ties aside), and every segment it leaves
    out is at least its clearance from every point of the cell (corners and random points)."""
    rng = np.random.default_rng(11)
    table = road_edge.build_segment_table(random_map(rng))
    idx = np.flatnonzero(table.valid)
    start, delta = table.start[idx], table.delta[idx]
    cells = road_edge.cell_candidate_table(start, delta, k=k)
    side, (num_x, num_y) = road_edge.CELL_SIDE, cells["shape"]
    rows = np.concatenate([rng.choice(num_x * num_y, 1500, replace=False), [0, num_x * num_y - 1]])
    offsets = (side / 2) * np.concatenate([rng.uniform(-1, 1, (6, 2)), [[-1, -1], [-1, 1], [1, -1], [1, 1]]])
    for row in rows:
        centre = cells["origin"].astype(np.float64) + (np.array(divmod(row, num_y)) + 0.5) * side
        listed = cells["candidates"][row]
        distance = planar_distances(centre[None], start, delta)[0]
        assert len(set(listed)) == min(k, len(idx))
        assert distance[listed].max() <= np.sort(distance)[min(k, len(idx)) - 1], row
        left_out = np.setdiff1d(np.arange(len(idx)), listed)
        nearest_left_out = planar_distances(centre + offsets, start[left_out], delta[left_out]).min()
        assert nearest_left_out >= cells["clearance"][row], (row, nearest_left_out, cells["clearance"][row])
        assert cells["clearance"][row] > nearest_left_out - 2 * side - 0.01, row  # and the bound is useful


def test_cell_tables_of_few_segments_list_them_all():
    table = road_edge.build_segment_table([polyline((0, 0), (10, 0), (10, 5))])
    cells = road_edge.cell_candidate_table(table.start[table.valid], table.delta[table.valid])
    assert set(np.unique(cells["candidates"])) == {0, 1}
    assert np.isinf(cells["clearance"]).all() and cells["candidates"].shape[1] == road_edge.CELL_CANDIDATES


def test_cell_tables_of_a_map_too_wide_settle_nothing():
    """Two road edges 140 km apart would need billions of 2 m cells: the table has one cell that
    settles no query, so every query searches all segments (exact, bounded memory)."""
    table = road_edge.build_segment_table([polyline((0, 0), (10, 0)), polyline((1e5, 1e5), (1e5, 1e5 + 10))])
    cells = road_edge.cell_candidate_table(table.start[table.valid], table.delta[table.valid])
    assert cells["candidates"].shape == (1, road_edge.CELL_CANDIDATES)
    assert (cells["clearance"] == -np.inf).all()
