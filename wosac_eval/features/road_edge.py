"""Signed distance from box corners to the road edge; offroad.

Road edges are polylines with the road on their left. For each query point the
relevant segment is the nearest one in 3D, with heights stretched 3x so that a
road edge on another level (a bridge) is not picked; the returned distance is
the planar distance to that segment, negative on the road side. Where the
point projects past a segment end, the sign follows the convexity of the
corner between the segment and its neighbour.

The search (compiled, `_nearest_segments`) needs one bound only: the selection
distance of a segment is at least the planar distance from the point to it,
and that changes by at most the distance the point moves. Segments are listed
in 16 m buckets once per scenario (`SegmentTable`); a 1 m cell where queries
fall gets, on first use, every segment that can be nearest anywhere in it,
sorted by distance from its centre, so a query evaluates the exact float32
distance of its first few candidates and stops at the first that cannot beat
it. Boxes are searched object by object, step by step, samples in a row, and
each query first tries the answer of the same corner of the box before: with
the best distance known at once, a candidate whose lower bound (float64, planar
distance and height gap, no division) is farther is not evaluated. Queries the
cell does not settle (on another level than every listed segment, far from the
map) search the buckets ring by ring around themselves.
Results equal an all-pairs search bit for bit (tests compare with brute force).
"""
from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np

from wosac_eval.features import ops
from wosac_eval.features.box_geometry import box_corners
from wosac_eval.features.compiled import cached_loop, compiled
from wosac_eval.features.spatial import column_bounds, finite_rows, non_finite_pick, pad_polylines


_F = np.float32
EXTREMELY_LARGE_DISTANCE = _F(1e10)
OFFROAD_DISTANCE_THRESHOLD = 0.0
Z_STRETCH = 3.0
_Z_STRETCH32 = _F(Z_STRETCH)
CYCLIC_TOLERANCE_M2 = 1.0
BUCKET_SIDE = 8.0  # metres: the planar buckets listing the segments that cross them
_GRID_BORDER = 256.0  # metres of buckets around the road edges' box: cells there get candidate lists


@dataclasses.dataclass(frozen=True)
class SegmentTable:
    """Road-edge segments flattened in the official (polyline, segment) order.

    Polylines are padded to the longest one, as the official code does; padding
    segments are invalid. Attributes are `(num_segments,)` or `(num_segments, 3)`,
    then the planar buckets of the compiled search (`_bucket_lists`).
    """

    start: np.ndarray        # float32 (S, 3)
    delta: np.ndarray        # float32 (S, 3): end - start
    valid: np.ndarray        # bool (S,)
    prior: np.ndarray        # int64 (S,): neighbour used when projecting before the start
    next: np.ndarray         # int64 (S,): neighbour used when projecting past the end
    prior_valid: np.ndarray  # bool (S,)
    next_valid: np.ndarray   # bool (S,)
    convex_before: np.ndarray  # bool (S,): left turn from the prior segment into this one
    convex_after: np.ndarray   # bool (S,): left turn from this segment into the next
    length: np.ndarray       # float64 (S,): |delta_xy| + 3 |delta_z|, for the float32 rounding margins
    frame: np.ndarray        # float64 (S, 7): start x, y, unit direction x, y, planar length, lowest and
                             # highest z (`_distance_bound`)
    bucket_origin: np.ndarray  # float64 (2,): the grid's lower corner
    bucket_side: float       # metres
    bucket_shape: np.ndarray   # int64 (2,): buckets along x, y; then those holding segments:
    segment_buckets: np.ndarray  # int64 (4,): first and last bucket along x, then along y
    bucket_start: np.ndarray   # int64 (num_buckets + 1,): where each bucket's list begins in
    bucket_segments: np.ndarray  # int32: valid segments crossing each bucket, bucket by bucket


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def _frames(start, delta):
    """float64 `(S, 7)`: each segment's start (x, y), planar unit direction (x, y), planar length, and
    lowest and highest z; a segment of no planar length gets the direction (1, 0) (`_distance_bound`)."""
    dx, dy = delta[:, 0].astype(np.float64), delta[:, 1].astype(np.float64)
    length = np.hypot(dx, dy)
    has = length > 0
    ux = np.where(has, dx / np.where(has, length, 1.0), 1.0)
    uy = np.where(has, dy / np.where(has, length, 1.0), 0.0)
    z0 = start[:, 2].astype(np.float64)
    z1 = z0 + delta[:, 2]
    return np.stack([start[:, 0].astype(np.float64), start[:, 1].astype(np.float64), ux, uy, length,
                     np.minimum(z0, z1), np.maximum(z0, z1)], axis=1)


def build_segment_table(polylines) -> SegmentTable:
    """Pads polylines to a common length, precomputes segment neighbours and buckets.

    Args:
      polylines: sequence of float32 `(num_points, 3)`; those with fewer than
        two points are ignored.
    """
    kept = [np.asarray(p, _F) for p in polylines if len(p) >= 2]
    if not kept:
        raise ValueError("the scenario has no road edges")
    num_points = max(len(p) for p in kept)
    seg = num_points - 1
    padded, point_valid = pad_polylines(kept, num_points)
    lengths = point_valid.sum(axis=1)
    gap = padded[:, 0] - padded[np.arange(len(kept)), lengths - 1]
    squared = gap * gap
    cyclic = (squared[:, 0] + squared[:, 1]) + squared[:, 2] < _F(CYCLIC_TOLERANCE_M2)
    start = padded[:, :-1]
    delta = padded[:, 1:] - padded[:, :-1]
    valid = point_valid[:, :-1] & point_valid[:, 1:]
    local = np.arange(seg)
    base = (np.arange(len(kept)) * seg)[:, None]
    # Neighbours wrap around only for cyclic polylines; elsewhere a segment is
    # its own neighbour at the ends, which leaves its sign unchanged.
    prior_local = np.where(local[None] > 0, local[None] - 1, np.where(cyclic[:, None], seg - 1, 0))
    next_local = np.where(local[None] < seg - 1, local[None] + 1, np.where(cyclic[:, None], 0, seg - 1))
    prior = (base + prior_local).reshape(-1)
    nxt = (base + next_local).reshape(-1)
    # Convexity always looks at the cyclically previous/next padded segment.
    dx, dy = delta[..., 0], delta[..., 1]
    wrap_prev = np.concatenate([delta[:, -1:], delta[:, :-1]], axis=1)
    wrap_next = np.concatenate([delta[:, 1:], delta[:, :1]], axis=1)
    convex_before = _cross(wrap_prev[..., 0], wrap_prev[..., 1], dx, dy) > 0
    convex_after = _cross(dx, dy, wrap_next[..., 0], wrap_next[..., 1]) > 0
    valid_flat = valid.reshape(-1)
    start, delta = np.ascontiguousarray(start.reshape(-1, 3)), np.ascontiguousarray(delta.reshape(-1, 3))
    return SegmentTable(
        start=start, delta=delta, valid=valid_flat,
        prior=prior, next=nxt, prior_valid=valid_flat[prior], next_valid=valid_flat[nxt],
        convex_before=convex_before.reshape(-1), convex_after=convex_after.reshape(-1),
        length=np.hypot(delta[:, 0].astype(np.float64), delta[:, 1]) + Z_STRETCH * np.abs(delta[:, 2].astype(np.float64)),
        frame=_frames(start, delta),
        **_bucket_grid(start, delta, valid_flat))


def segment_distances(px, py, pz, sx, sy, sz, dx, dy, dz):
    """Projection parameter, stretched 3D distance and planar distance, float32.

    Elementwise (broadcasting) over points p, segment starts s and segment
    vectors d, in the official order of float32 operations (an `ops` kernel:
    numpy, JAX, or compiled for the search loop).
    """
    tx, ty, tz = px - sx, py - sy, pz - sz
    along = tx * dx + ty * dy
    squared = dx * dx + dy * dy
    rel_t = ops.where(squared == _F(0), _F(0), ops.divide(along, squared))
    clipped = ops.clip(rel_t, _F(0), _F(1))
    ox, oy = tx - dx * clipped, ty - dy * clipped
    oz = (tz - dz * clipped) * _Z_STRETCH32
    planar2 = ox * ox + oy * oy
    return rel_t, ops.sqrt(planar2 + oz * oz), ops.sqrt(planar2)


def segment_side(query_xy, start, delta):
    """Sign of the cross product: +1 on the right (off-road) side of a segment.

    Args:
      query_xy: float32 `(..., 2)`; start, delta: float32 `(..., 3)` (or `(..., 2)`).
    Returns:
      float32 `(...)` in {-1, 0, 1}.
    """
    return side_of_segment(query_xy[..., 0], query_xy[..., 1], start[..., 0], start[..., 1],
                           delta[..., 0], delta[..., 1])


def side_of_segment(px, py, sx, sy, dx, dy):
    """`segment_side` on separate coordinates (an elementwise `ops` kernel)."""
    return ops.sign((px - sx) * dy - (py - sy) * dx)


def corner_sign(rel_t, n, n_prior, n_next, convex_before, convex_after, prior_valid, next_valid):
    """Side of the nearest segment, corrected where the point projects past an end.

    Past an end the sign follows the corner with the neighbour segment: on a
    convex corner the point is off-road if it is on the right of either
    segment, on a concave one only if it is on the right of both.
    An elementwise `ops` kernel: all arguments are `(...)` arrays or scalars.
    """
    before = ops.where(convex_before, ops.maximum(n, n_prior), ops.minimum(n, n_prior))
    after = ops.where(convex_after, ops.maximum(n, n_next), ops.minimum(n, n_next))
    return ops.where((rel_t < _F(0)) & prior_valid, before, ops.where((rel_t > _F(1)) & next_valid, after, n))


# --- The compiled search ---------------------------------------------------------------------------

_MAX_BUCKETS = 1 << 20  # larger maps get larger buckets (the grid's memory stays bounded)
_CELLS_PER_BUCKET = 8  # along each axis: cells of BUCKET_SIDE / 8 (1 m)
_LIST_SLACK = 3.0  # metres listed beyond a cell's nearest planar distance: heights up to 1 m apart
_NOT_FOUND = _OFF_GRID = -1
_NON_FINITE = -2


def _bucket_grid(start: np.ndarray, delta: np.ndarray, valid: np.ndarray) -> dict:
    """The planar buckets of the compiled search: the road edges' box with `_GRID_BORDER` around it,
    in squares of `BUCKET_SIDE` (doubled until there are at most `_MAX_BUCKETS`), each listing the
    valid segments whose box overlaps it."""
    listed = valid & finite_rows(start) & finite_rows(delta)
    ends = np.concatenate([start[listed, :2], start[listed, :2] + delta[listed, :2]]).astype(np.float64)
    if not len(ends):
        ends = np.zeros((1, 2))
    side = BUCKET_SIDE
    low, high = column_bounds(ends)
    while True:
        origin = np.floor((low - _GRID_BORDER) / side) * side
        shape = np.ceil((high + _GRID_BORDER - origin) / side).astype(np.int64) + 1
        if shape[0] * shape[1] <= _MAX_BUCKETS:
            break
        side *= 2
    bucket_start, bucket_segments, occupied = _bucket_lists(start, delta, listed, origin[0], origin[1], side,
                                                            shape[0], shape[1])
    return {"bucket_origin": origin, "bucket_side": side, "bucket_shape": shape, "segment_buckets": occupied,
            "bucket_start": bucket_start, "bucket_segments": bucket_segments}


@numba.njit(cache=True)
def _bucket_lists(start, delta, listed, origin_x, origin_y, side, num_x, num_y):
    """(list starts `(num_buckets + 1,)`, segments bucket by bucket, the occupied range [x0, x1, y0, y1])."""
    counts = np.zeros(num_x * num_y + 1, np.int64)
    occupied = np.array([num_x, -1, num_y, -1], np.int64)
    for k in range(start.shape[0]):
        if not listed[k]:
            continue
        x0, x1 = _bucket_range(start[k, 0], delta[k, 0], origin_x, side, num_x)
        y0, y1 = _bucket_range(start[k, 1], delta[k, 1], origin_y, side, num_y)
        occupied[0], occupied[1] = min(occupied[0], x0), max(occupied[1], x1)
        occupied[2], occupied[3] = min(occupied[2], y0), max(occupied[3], y1)
        for i in range(x0, x1 + 1):
            for j in range(y0, y1 + 1):
                counts[i * num_y + j + 1] += 1
    bucket_start = np.cumsum(counts)
    fill = bucket_start[:-1].copy()
    segments = np.empty(bucket_start[-1], np.int32)
    for k in range(start.shape[0]):
        if not listed[k]:
            continue
        x0, x1 = _bucket_range(start[k, 0], delta[k, 0], origin_x, side, num_x)
        y0, y1 = _bucket_range(start[k, 1], delta[k, 1], origin_y, side, num_y)
        for i in range(x0, x1 + 1):
            for j in range(y0, y1 + 1):
                segments[fill[i * num_y + j]] = k
                fill[i * num_y + j] += 1
    return bucket_start, segments, occupied


@numba.njit
def _ring_buffer(grid):
    """Room for the buckets of one ring within the grid's occupied range (`_ring_buckets`)."""
    origin_x, origin_y, side, num_x, num_y, x0, x1, y0, y1 = grid
    return np.empty(2 * (max(x1 - x0, 0) + max(y1 - y0, 0)) + 4, np.int64)


@numba.njit
def _rings_around(x, y, grid):
    """The bucket (bi, bj) of a point and the first and last rings around it that meet the
    occupied range (`_ring_buckets`)."""
    origin_x, origin_y, side, num_x, num_y, x0, x1, y0, y1 = grid
    bi, bj = _bucket_of(x, origin_x, side), _bucket_of(y, origin_y, side)
    return bi, bj, max(0, x0 - bi, bi - x1, y0 - bj, bj - y1), max(x1 - bi, bi - x0, y1 - bj, bj - y0)


@numba.njit
def _ring_buckets(bi, bj, r, grid, out):
    """The buckets r steps (Chebyshev) from bucket (bi, bj) within the occupied range, into `out`;
    returns their count."""
    origin_x, origin_y, side, num_x, num_y, x0, x1, y0, y1 = grid
    n = 0
    for i in range(max(bi - r, x0), min(bi + r, x1) + 1):
        if i == bi - r or i == bi + r:  # a whole row of the ring
            for j in range(max(bj - r, y0), min(bj + r, y1) + 1):
                out[n] = i * num_y + j
                n += 1
        else:  # the row's two ends
            if y0 <= bj - r <= y1:
                out[n] = i * num_y + bj - r
                n += 1
            if r > 0 and y0 <= bj + r <= y1:
                out[n] = i * num_y + bj + r
                n += 1
    return n


@numba.njit
def _bucket_of(value, origin, side):
    """The bucket index along one axis of a finite coordinate (`_bucket_coordinate`'s floor)."""
    return int(math.floor(_bucket_coordinate(value, origin, side)))


@numba.njit
def _bucket_coordinate(value, origin, side):
    """Where a finite coordinate lies along one axis, in buckets from the grid's origin, clamped far
    beyond any grid (an integer conversion of a huge float is undefined). The side is a power of two
    (`_bucket_grid`): multiplying by its inverse (hoisted out of callers' loops) is exact, where a
    division per coordinate was most of `_query_cells`' time."""
    return min(max((value - origin) * (1.0 / side), -1e15), 1e15)


@numba.njit
def _bucket_range(start, delta, origin, side, num):
    """Buckets along one axis overlapped by a segment (clamped to the grid)."""
    low, high = min(start, start + delta), max(start, start + delta)
    first = _bucket_of(np.float64(low), origin, side)
    last = _bucket_of(np.float64(high), origin, side)
    return max(0, min(first, num - 1)), max(0, min(last, num - 1))


_segment_distances = compiled(segment_distances)
_side_of = compiled(side_of_segment)
_corner_sign = compiled(corner_sign)


@numba.njit
def _planar_squared(qx, qy, k, frame):
    """The squared planar distance (float64) from a point to segment k, in the segment's own frame (no
    division). Its rounding, about 1e-16 of the coordinates, is far inside `_rounding_margin`."""
    tx, ty = qx - frame[k, 0], qy - frame[k, 1]
    along = tx * frame[k, 2] + ty * frame[k, 3]
    across = tx * frame[k, 3] - ty * frame[k, 2]
    beyond = max(-along, along - frame[k, 4], 0.0)
    return beyond * beyond + across * across


@numba.njit
def _planar_distance64(cx, cy, k, frame):
    """Planar distance (float64) from a point to segment k: a lower bound of its selection distance."""
    return math.sqrt(_planar_squared(cx, cy, k, frame))


@numba.njit
def _distance_bound(qx, qy, qz, k, frame):
    """A lower bound of the squared selection distance from a point to segment k (float64, no division):
    the squared planar distance to the segment plus the stretched squared height gap to its z range
    (every point of the segment is at least that far in each)."""
    below = max(frame[k, 5] - qz, qz - frame[k, 6], 0.0) * Z_STRETCH
    return _planar_squared(qx, qy, k, frame) + below * below


@numba.njit
def _rounding_margin(distance, length):
    """How far below the true distance the float32 selection distance can fall (generously)."""
    return 1e-3 + 1e-5 * (distance + 2.0 * length)


@numba.njit
def _selection(px, py, pz, k, start, delta):
    return _segment_distances(px, py, pz, start[k, 0], start[k, 1], start[k, 2],
                                 delta[k, 0], delta[k, 1], delta[k, 2])[1]


@cached_loop
def _ring_search(px, py, pz, start, delta, grid, bucket_start, bucket_segments, seen, tag, ring, max_length):
    """The nearest segment of one point by expanding rings of buckets around it (exact, any point).

    Before ring r, every segment not met yet crosses only buckets r or more buckets away,
    so it is at least (r - 1) * side away in the plane: the search stops there.
    """
    if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
        return _NON_FINITE, 0
    side = grid[2]
    bi, bj, first, last = _rings_around(np.float64(px), np.float64(py), grid)
    best, best_k, evaluated = np.float32(np.inf), _NOT_FOUND, 0
    for r in range(first, last + 1):
        if r > first and (r - 1) * side > best + _rounding_margin(best, max_length):
            break
        for q in range(_ring_buckets(bi, bj, r, grid, ring)):
            for p in range(bucket_start[ring[q]], bucket_start[ring[q] + 1]):
                k = bucket_segments[p]
                if seen[k] == tag:
                    continue
                seen[k] = tag
                d = _selection(px, py, pz, k, start, delta)
                evaluated += 1
                if d < best or (d == best and k < best_k):
                    best, best_k = d, k
    return best_k, evaluated


@numba.njit(error_model="numpy")
def _cell_candidates(cx, cy, half_diagonal, min_reach, frame, length, grid, bucket_start, bucket_segments, seen,
                     tag, ring, out_segment, out_key):
    """Every segment that can be nearest somewhere in a cell, by key; returns (count, clearance).

    For a point q within r of the centre c, segment k's planar distance is at least
    P_k(c) - r: segments with P_k(c) - h above R = min_k P_k(c) + h + slack are left out, and a
    query settles when what it found is nearer than what they can reach. The key of a listed
    segment is P_k(c) less its rounding margin; lists are sorted by key.
    """
    side = grid[2]
    bi, bj, first, last = _rings_around(cx, cy, grid)
    reach = np.inf  # R
    n = 0
    for r in range(first, last + 1):
        if r > first and (r - 1) * side - half_diagonal > reach:
            break
        gathered = _gather_ring(cx, cy, bi, bj, r, frame, grid, bucket_start, bucket_segments, seen, tag, ring,
                                out_segment, out_key, n)
        for p in range(n, gathered):
            reach = min(reach, max(out_key[p] + half_diagonal + _LIST_SLACK, min_reach))
        n = gathered
    return _listed(n, reach, half_diagonal, length, out_segment, out_key), reach


@numba.njit
def _gather_ring(cx, cy, bi, bj, r, frame, grid, bucket_start, bucket_segments, seen, tag, ring, out_segment,
                 out_key, n):
    """Appends the segments of the buckets r rings around bucket (bi, bj) not met yet (`seen` is not
    `tag`), with their planar distance from (cx, cy), to `out_segment` and `out_key` from `n`;
    returns the new count. Before ring r, a segment not met yet is at least (r - 1) buckets away."""
    for q in range(_ring_buckets(bi, bj, r, grid, ring)):
        for p in range(bucket_start[ring[q]], bucket_start[ring[q] + 1]):
            k = bucket_segments[p]
            if seen[k] != tag:
                seen[k] = tag
                out_segment[n], out_key[n] = k, _planar_distance64(cx, cy, k, frame)
                n += 1
    return n


@numba.njit
def _listed(n, reach, half_diagonal, length, out_segment, out_key):
    """Keeps the gathered segments (first n of `out_segment`, their centre distances in `out_key`)
    that can be nearest in the cell, keyed and sorted; returns their count.

    An insertion sort: segments come gathered near to far from a point near the cell (the
    cell's parent bucket's order), so each moves a few places at most.
    """
    m = 0
    for p in range(n):
        if out_key[p] - half_diagonal <= reach:
            k = out_segment[p]
            value = out_key[p] * (1 - 1e-5) - _rounding_margin(0.0, length[k])
            q = m
            while q > 0 and out_key[q - 1] > value:
                out_segment[q], out_key[q] = out_segment[q - 1], out_key[q - 1]
                q -= 1
            out_segment[q], out_key[q] = k, value
            m += 1
    return m


@numba.njit
def _cell_candidates_among(cx, cy, half_diagonal, frame, length, among, among_key, count, shift, out_segment, out_key):
    """`_cell_candidates` of a cell inside a square whose list `among[:count]` holds every segment that
    can be nearest in it (a cell's list is a subset of that of a square around it: its bounds are
    tighter); returns (count, clearance).

    `among_key` are the square's keys (sorted, each at most the segment's distance from the square's
    centre), `shift` the distance between the two centres: a segment's distance from the cell's centre
    is at least its key less `shift`, so the scan stops at the first whose key shows it can be
    neither listed nor nearer than the reach so far (nor can any after it).
    """
    reach = np.inf
    n = 0
    for p in range(count):
        if among_key[p] - shift - half_diagonal > reach:
            break
        k = among[p]
        d = _planar_distance64(cx, cy, k, frame)
        reach = min(reach, d + half_diagonal + _LIST_SLACK)
        out_segment[n] = k
        out_key[n] = d
        n += 1
    return _listed(n, reach, half_diagonal, length, out_segment, out_key), reach


@numba.njit(cache=True)
def _query_cells(queries, grid, bucket_start):
    """The cell of each query, numbered as first met, and each cell's centre and half-diagonal.

    Cells are 1 m (a 16th of a bucket) where the 5 x 5 buckets around hold a segment; farther
    out one list serves a whole bucket (cells of 1 m there would each list a wide ring of segments).

    Returns:
      (cell int64 `(n,)`: `_OFF_GRID` for a point off the grid, `_NON_FINITE` for one with a NaN
      or infinite coordinate; centre float64 `(num_cells, 2)`; half-diagonal float64 `(num_cells,)`).
    """
    origin_x, origin_y, side, num_x, num_y, x0, x1, y0, y1 = grid
    n = queries.shape[0]
    cell = np.empty(n, np.int64)  # the bucket first, then the cell
    within = np.empty((n, 2), np.float64)  # where in its bucket a query lies, in [0, 1)
    block_of_bucket = np.full(num_x * num_y, -1, np.int64)
    num_blocks = 0
    for i in range(n):
        px, py = np.float64(queries[i, 0]), np.float64(queries[i, 1])
        if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(queries[i, 2])):
            cell[i] = _NON_FINITE
            continue
        # Its place in its bucket is kept for the second pass (computed twice, it cost as much again).
        fx, fy = _bucket_coordinate(px, origin_x, side), _bucket_coordinate(py, origin_y, side)
        bi, bj = math.floor(fx), math.floor(fy)
        if not (0 <= bi < num_x and 0 <= bj < num_y):
            cell[i] = _OFF_GRID
            continue
        b = int(bi) * num_y + int(bj)
        cell[i] = b
        within[i, 0], within[i, 1] = fx - bi, fy - bj
        if block_of_bucket[b] < 0:
            block_of_bucket[b] = num_blocks
            num_blocks += 1
    division = np.empty(num_blocks, np.int64)  # cells per bucket side
    for b in range(num_x * num_y):
        if block_of_bucket[b] >= 0:
            near = _segments_around(b // num_y, b % num_y, 2, grid, bucket_start)
            division[block_of_bucket[b]] = _CELLS_PER_BUCKET if near else 1
    cell_id = np.full((num_blocks, _CELLS_PER_BUCKET * _CELLS_PER_BUCKET), -1, np.int64)
    centre = np.empty((min(n, num_blocks * _CELLS_PER_BUCKET * _CELLS_PER_BUCKET), 2), np.float64)
    half_diagonal = np.empty(centre.shape[0], np.float64)
    num_cells = 0
    for i in range(n):
        b = cell[i]
        if b < 0:  # _OFF_GRID and _NON_FINITE stay
            continue
        block = block_of_bucket[b]
        per_side = division[block]
        ci = min(int(within[i, 0] * per_side), per_side - 1)
        cj = min(int(within[i, 1] * per_side), per_side - 1)
        local = ci * per_side + cj
        c = cell_id[block, local]
        if c < 0:
            c = num_cells
            cell_id[block, local] = c
            size = side / per_side
            centre[c, 0] = origin_x + (b // num_y) * side + (ci + 0.5) * size
            centre[c, 1] = origin_y + (b % num_y) * side + (cj + 0.5) * size
            half_diagonal[c] = size * math.sqrt(0.5)
            num_cells += 1
        cell[i] = c
    return cell, centre[:num_cells], half_diagonal[:num_cells]


@cached_loop
def _cell_lists(centre, half_diagonal, min_reach, frame, length, grid, bucket_start, bucket_segments):
    """The candidate list of each cell (`_cell_candidates`), one after the other.

    Returns:
      (begin, end int64 `(num_cells,)`: where each cell's list lies in segment int32 and key
      float64 `(list entries,)`; reach float64 `(num_cells,)`: the R of each cell).
    """
    num_cells, num_segments = centre.shape[0], frame.shape[0]
    begin, end = np.zeros(num_cells, np.int64), np.zeros(num_cells, np.int64)
    reach = np.empty(num_cells, np.float64)
    segment = np.empty(max(16, 32 * num_cells), np.int32)
    key = np.empty(segment.shape[0], np.float64)
    seen = np.full(num_segments, -1, np.int64)
    scratch_segment = np.empty(num_segments, np.int32)
    scratch_key = np.empty(num_segments, np.float64)
    ring = _ring_buffer(grid)
    origin_x, origin_y, side = grid[0], grid[1], grid[2]
    # Cells smaller than a bucket take their segments among those of their bucket, built once.
    parent = np.empty(num_cells, np.int64)
    for c in range(num_cells):
        inside = half_diagonal[c] < side * math.sqrt(0.5) and min_reach[c] == 0
        parent[c] = _bucket_of(centre[c, 0], origin_x, side) * grid[4] + _bucket_of(centre[c, 1], origin_y, side) \
            if inside else -1
    order = np.argsort(parent)
    bucket_list, bucket_key = np.empty(num_segments, np.int32), np.empty(num_segments, np.float64)
    bucket_count, current, used = 0, -2, 0
    bucket_x = bucket_y = 0.0
    for c in order:
        if parent[c] >= 0 and parent[c] != current:
            current = parent[c]
            bi, bj = current // grid[4], current % grid[4]
            bucket_x, bucket_y = origin_x + (bi + 0.5) * side, origin_y + (bj + 0.5) * side
            bucket_count, _ = _cell_candidates(bucket_x, bucket_y, side * math.sqrt(0.5), 0.0, frame, length, grid,
                                               bucket_start, bucket_segments, seen, num_cells + c, ring, bucket_list,
                                               bucket_key)
        if parent[c] >= 0:
            shift = math.hypot(centre[c, 0] - bucket_x, centre[c, 1] - bucket_y)
            m, reach[c] = _cell_candidates_among(centre[c, 0], centre[c, 1], half_diagonal[c], frame, length,
                                                 bucket_list, bucket_key, bucket_count, shift, scratch_segment,
                                                 scratch_key)
        else:
            m, reach[c] = _cell_candidates(centre[c, 0], centre[c, 1], half_diagonal[c], min_reach[c], frame, length,
                                           grid, bucket_start, bucket_segments, seen, c, ring, scratch_segment,
                                           scratch_key)
        while used + m > segment.shape[0]:
            segment, key = _grown(segment), _grown(key)
        segment[used:used + m] = scratch_segment[:m]
        key[used:used + m] = scratch_key[:m]
        begin[c], end[c] = used, used + m
        used += m
    return begin, end, segment[:used], key[:used], reach


@cached_loop
def _search_lists(queries, cell, centre, half_diagonal, begin, end, segment, key, reach, max_length, start, delta,
                  frame, hint_stride):
    """The nearest segment of each query among its cell's list.

    The nearest segment of the query `hint_stride` before (the same corner of a nearby box, in
    the order `box_distance_to_road_edge` gives) is evaluated first: usually the answer, so that
    few others pass the bounds. Then candidates are taken in key order until the next one's key
    shows that nothing further on can be nearer; a candidate that `_distance_bound` puts farther
    than the best so far is not evaluated. (Any valid segment may be evaluated: the result is
    the nearest of those evaluated, and the bounds cover every segment that could beat it.)

    Returns:
      (int64 `(n,)`: the segment, `_NOT_FOUND` where the list does not settle it (or the query
      has no cell), `_NON_FINITE` for a NaN or infinite point; float64 `(num_cells,)`: the R a
      cell's list needs to settle all its queries, 0 where it does; the number of distances
      evaluated).
    """
    out = np.empty(queries.shape[0], np.int64)
    needed = np.zeros(centre.shape[0], np.float64)
    evaluated = 0
    margin = _rounding_margin(0.0, max_length)
    for i in range(queries.shape[0]):
        px, py, pz = queries[i, 0], queries[i, 1], queries[i, 2]
        c = cell[i]
        if c < 0:  # off the grid (not found here) or not finite
            out[i] = c
            continue
        qx, qy, qz = np.float64(px), np.float64(py), np.float64(pz)
        ox, oy = qx - centre[c, 0], qy - centre[c, 1]
        off_centre = math.sqrt(ox * ox + oy * oy)
        best, best_k, reject = np.float32(np.inf), _NOT_FOUND, np.inf
        hint = out[i - hint_stride] if i >= hint_stride else _NOT_FOUND
        if hint >= 0:
            evaluated += 1
            best = _selection(px, py, pz, hint, start, delta)
            best_k = hint
            bound = np.float64(best) + _rounding_margin(np.float64(best), max_length)
            reject = bound * bound
        for p in range(begin[c], end[c]):
            if key[p] - off_centre > best:
                break
            k = segment[p]
            if k == best_k or _distance_bound(qx, qy, qz, k, frame) > reject:
                continue
            evaluated += 1
            d = _selection(px, py, pz, k, start, delta)
            if d < best or (d == best and k < best_k):
                best, best_k = d, k
                bound = np.float64(best) + _rounding_margin(np.float64(best), max_length)
                reject = bound * bound
        # A segment left out is farther in the plane than this, less its rounding.
        unlisted = (reach[c] + half_diagonal[c] - off_centre) * (1 - 1e-5) - margin
        if best < unlisted:
            out[i] = best_k
        else:
            out[i] = _NOT_FOUND
            if best_k >= 0:  # R that would settle it (on another level than the listed segments)
                needed[c] = max(needed[c], (best + margin) / (1 - 1e-5) + off_centre - half_diagonal[c] + 1e-3)
    return out, needed, evaluated


@cached_loop
def _ring_searches(queries, found, start, delta, grid, bucket_start, bucket_segments, max_length):
    """`_ring_search` for every query `found` left `_NOT_FOUND` (in place); returns the distances evaluated."""
    seen = np.full(start.shape[0], -1, np.int64)
    ring = _ring_buffer(grid)
    evaluated = 0
    for i in range(queries.shape[0]):
        if found[i] == _NOT_FOUND:
            found[i], count = _ring_search(queries[i, 0], queries[i, 1], queries[i, 2], start, delta, grid,
                                           bucket_start, bucket_segments, seen, i, ring, max_length)
            evaluated += count
    return evaluated


_FAR_CELL_RATIO = 1024.0  # a cell off the grid is about this many times smaller than its distance to the map


def _with_far_cells(queries, cell, centre, half_diagonal, table: SegmentTable):
    """`_query_cells` with cells for the finite points off the grid (placeholder states, a rollout
    gone kilometres away): squares of a power-of-two side, about 1/1024 of their distance to
    the map and at least a bucket, so one list serves the points near one another."""
    far = np.flatnonzero(cell == _OFF_GRID)
    if not far.size:
        return cell, centre, half_diagonal
    xy = queries[far, :2].astype(np.float64)
    side = table.bucket_side
    low = table.bucket_origin + table.segment_buckets[[0, 2]] * side
    high = table.bucket_origin + (table.segment_buckets[[1, 3]] + 1) * side
    gap = np.maximum(np.maximum(low - xy, xy - high), 0.0)
    size = 2.0 ** np.ceil(np.log2(np.maximum(np.hypot(gap[:, 0], gap[:, 1]) / _FAR_CELL_RATIO, side)))
    key = np.stack([np.floor(xy[:, 0] / size), np.floor(xy[:, 1] / size), size], axis=1)
    # The distinct squares, by a numeric sort of the rows (numpy's unique over rows compares their bytes,
    # which takes milliseconds for a few thousand rows).
    order = np.lexsort(key.T[::-1])
    ordered = key[order]
    first = np.ones(len(ordered), bool)
    first[1:] = (ordered[1:] != ordered[:-1]).any(axis=1)
    squares = ordered[first]
    which = np.empty(len(key), np.int64)
    which[order] = np.cumsum(first) - 1
    cell = cell.copy()
    cell[far] = len(centre) + which.reshape(-1)
    centre = np.concatenate([centre, (squares[:, :2] + 0.5) * squares[:, 2:]])
    half_diagonal = np.concatenate([half_diagonal, squares[:, 2] * np.sqrt(0.5)])
    return cell, centre, half_diagonal


def _nearest_segments(queries, table: SegmentTable, counts: dict | None = None, hint_stride: int = 1) -> np.ndarray:
    """The nearest valid segment of each point (stretched selection distance, lowest index on ties).

    Args:
      queries: float32 `(n, 3)`, contiguous.
      counts: a dict that gets the work done: "cells" (candidate lists built), "pairs evaluated"
        (selection distances computed).
      hint_stride: each query starts from the answer of the query this many before it (a hint only:
        the result does not depend on it; it saves work where that query is near).
    Returns:
      int64 `(n,)`: a segment, `_NOT_FOUND` when no segment is listed, `_NON_FINITE` for a point
      with a NaN or infinite coordinate.
    """
    grid = (*(float(v) for v in table.bucket_origin), float(table.bucket_side),
            *(int(v) for v in table.bucket_shape), *(int(v) for v in table.segment_buckets))
    cell, centre, half_diagonal = _query_cells(queries, grid, table.bucket_start)
    cell, centre, half_diagonal = _with_far_cells(queries, cell, centre, half_diagonal, table)
    max_length = float(table.length[table.bucket_segments].max(initial=0.0))
    work = {"cells": 0, "pairs evaluated": 0}

    def search(rows, cells, min_reach):
        lists = _cell_lists(centre[cells], half_diagonal[cells], min_reach, table.frame, table.length, grid,
                            table.bucket_start, table.bucket_segments)
        number = np.full(len(centre) + 2, -1, np.int64)
        number[cells] = np.arange(len(cells))
        number[_NON_FINITE] = _NON_FINITE  # the codes of queries without a cell stay
        found, needed, evaluated = _search_lists(queries[rows], number[cell[rows]], centre[cells],
                                                 half_diagonal[cells], *lists, max_length, table.start, table.delta,
                                                 table.frame, hint_stride)
        work["cells"] += len(cells)
        work["pairs evaluated"] += evaluated
        return found, needed

    found, needed = search(slice(None), np.arange(len(centre)), np.zeros(len(centre)))
    # Cells whose list left queries unsettled (a box on another level than the road edges near it):
    # their lists grown to settle them, once per cell; whatever is left searches the buckets.
    grow = np.flatnonzero(needed > 0)
    if grow.size:
        again = np.flatnonzero((found == _NOT_FOUND) & np.isin(cell, grow))
        found[again] = search(again, grow, needed[grow])[0]
    if (found == _NOT_FOUND).any():
        work["pairs evaluated"] += _ring_searches(queries, found, table.start, table.delta, grid, table.bucket_start,
                                                  table.bucket_segments, max_length)
    if counts is not None:
        counts.update(work)
    return found


@numba.njit
def _segments_around(bi, bj, r, grid, bucket_start):
    """Whether a bucket within `r` buckets of (bi, bj) lists a segment."""
    origin_x, origin_y, side, num_x, num_y, x0, x1, y0, y1 = grid
    for i in range(max(bi - r, 0), min(bi + r, num_x - 1) + 1):
        for j in range(max(bj - r, 0), min(bj + r, num_y - 1) + 1):
            if bucket_start[i * num_y + j + 1] > bucket_start[i * num_y + j]:
                return True
    return False


@numba.njit
def _grown(a):
    """`a` in an array twice as long (first axis), its rows kept."""
    out = np.empty((2 * a.shape[0],) + a.shape[1:], a.dtype)
    out[:a.shape[0]] = a
    return out


@cached_loop
def _signed_distances(queries, segment, start, delta, valid, prior, next_, prior_valid, next_valid, convex_before,
                      convex_after, group):
    """Signed planar distance of each point to its nearest segment (`segment`, `(n,)`): the largest of
    each `group` of consecutive points (numpy's maximum: NaN passes on), float32 `(n // group,)`."""
    out = np.empty(queries.shape[0] // group, np.float32)
    for i in range(queries.shape[0]):
        px, py, pz, k = queries[i, 0], queries[i, 1], queries[i, 2], segment[i]
        rel_t, _, planar = _segment_distances(px, py, pz, start[k, 0], start[k, 1], start[k, 2],
                                                 delta[k, 0], delta[k, 1], delta[k, 2])
        a, b = prior[k], next_[k]
        side = _side_of(px, py, start[k, 0], start[k, 1], delta[k, 0], delta[k, 1])
        # The neighbours' sides count only past the segment's ends (`corner_sign`).
        side_prior = _side_of(px, py, start[a, 0], start[a, 1], delta[a, 0], delta[a, 1]) if rel_t < 0 else side
        side_next = _side_of(px, py, start[b, 0], start[b, 1], delta[b, 0], delta[b, 1]) if rel_t > 1 else side
        sign = _corner_sign(rel_t, side, side_prior, side_next, convex_before[k], convex_after[k],
                            prior_valid[k], next_valid[k])
        # A padding segment's distance is 1e10, as officially (only non-finite points get one).
        distance = sign * (planar if valid[k] else EXTREMELY_LARGE_DISTANCE)
        g = i // group
        out[g] = distance if i % group == 0 or not ((out[g] > distance) | (out[g] != out[g])) else out[g]
    return out


def nearest_segments(table: SegmentTable, queries: np.ndarray, counts: dict | None = None,
                     hint_stride: int = 1) -> np.ndarray:
    """Index of the nearest road-edge segment of each point, as the official all-pairs search picks it.

    Args:
      queries: float32 `(num_points, 3)`.
      counts: optional dict that gets the search's work ("cells", "pairs evaluated").
      hint_stride: the query whose answer each query tries first, this many before it (`_nearest_segments`).
    Returns:
      int64 `(num_points,)`; a point with a NaN or infinite coordinate gets the official pick
      (`spatial.non_finite_pick`).
    """
    found = _nearest_segments(np.ascontiguousarray(queries, _F), table, counts, hint_stride)
    if found.min(initial=0) < 0:  # rare: most scenes have no non-finite corner
        found = np.where(found < 0, non_finite_pick(table.valid), found)
    return found


def signed_distance_to_polylines(table: SegmentTable, queries: np.ndarray) -> np.ndarray:
    """Signed planar distance from points to the road-edge boundary.

    Args:
      table: the road edges, from `build_segment_table`.
      queries: float32 `(num_points, 3)`.
    Returns:
      float32 `(num_points,)`, negative on the road side.
    """
    return _signed_distance_groups(table, np.ascontiguousarray(queries, _F).reshape(-1, 3), 1)


def _signed_distance_groups(table: SegmentTable, queries: np.ndarray, group: int, counts: dict | None = None):
    # The same corner of the box before is the hint (`_nearest_segments`).
    segment = nearest_segments(table, queries, counts, hint_stride=group)
    return _signed_distances(queries, segment, table.start, table.delta, table.valid, table.prior, table.next,
                             table.prior_valid, table.next_valid, table.convex_before, table.convex_after, group)


def box_distance_to_road_edge(x, y, bottom, length, width, cos_h, sin_h, valid, table: SegmentTable,
                              counts: dict | None = None) -> np.ndarray:
    """Signed distance of the most off-road bottom corner of each box.

    The corners (`box_geometry.box_corners` at the height `bottom`) are computed in the search's
    order by a compiled loop, with no array of corners.

    Args:
      x, y, bottom, length, width, cos_h, sin_h: float32 `(..., num_objects, num_steps)`.
      valid: bool, the same shape.
      counts: optional dict that gets the search's work (`nearest_segments`).
    Returns:
      float32 `(..., num_objects, num_steps)`; -1e10 where invalid.
    """
    shape = np.shape(x)
    # Only valid boxes are searched: invalid log states sit at placeholder positions (often the
    # origin, kilometres from the map) and are masked anyway. They are searched object by object,
    # step by step, the samples of each step in a row: boxes in a row are near one another, so one's
    # answer is a good hint for the next and their candidate lists stay in the cache.
    by_box = lambda a: np.ascontiguousarray(np.moveaxis(np.reshape(a, (-1,) + shape[-2:]), 0, -1))  # noqa: E731
    queries, keep = _box_corner_queries(*(by_box(np.asarray(a, _F)) for a in (x, y, bottom, length, width, cos_h,
                                                                            sin_h)), by_box(valid))
    out = np.full((shape[-2], shape[-1], int(np.prod(shape[:-2], dtype=np.int64))), -EXTREMELY_LARGE_DISTANCE, _F)
    out.reshape(-1)[keep] = _signed_distance_groups(table, queries, 4, counts)
    return np.ascontiguousarray(np.moveaxis(out, -1, 0)).reshape(shape)


_box_corners = compiled(box_corners)


@cached_loop
def _box_corner_queries(x, y, bottom, length, width, cos_h, sin_h, valid):
    """The 4 corners (x, y, bottom) of each valid box, float32 `(4 * num_valid, 3)`, and the valid boxes'
    flat indices, int64 `(num_valid,)`, in their flat order; the arguments are arrays of one shape `(...)`."""
    flat = valid.reshape(-1)
    keep = np.flatnonzero(flat)
    queries = np.empty((4 * keep.shape[0], 3), np.float32)
    xs, ys, bs = x.reshape(-1), y.reshape(-1), bottom.reshape(-1)
    ls, ws, cs, ss = length.reshape(-1), width.reshape(-1), cos_h.reshape(-1), sin_h.reshape(-1)
    for i in range(keep.shape[0]):
        k = keep[i]
        x0, x1, x2, x3, y0, y1, y2, y3 = _box_corners(xs[k], ys[k], ls[k], ws[k], cs[k], ss[k])
        queries[4 * i, 0], queries[4 * i + 1, 0], queries[4 * i + 2, 0], queries[4 * i + 3, 0] = x0, x1, x2, x3
        queries[4 * i, 1], queries[4 * i + 1, 1], queries[4 * i + 2, 1], queries[4 * i + 3, 1] = y0, y1, y2, y3
        queries[4 * i:4 * i + 4, 2] = bs[k]
    return queries, keep


# --- Cell tables for fixed-shape searches (the JAX driver, features/dense.py) ----------------------

# Measured on the two real WOMD scenes' box corners (IDM rollouts): 4 m cells of 32 settled 64% of the
# queries (the rest searched every segment), 2 m cells of 64 settle 99.5-99.9%.
CELL_SIDE = 2.0  # metres: the planar grid of the candidate tables (a power of two: exact cell indices)
CELL_CANDIDATES = 64  # segments listed per cell
_CELL_BORDER = 10.0  # metres of grid around the segments' box
_GROUP_CELLS = 4  # cells along each side of a group that gathers its segments once
_MAX_CELLS = 1 << 20  # a larger grid (a map over 2 km across) gets a table that settles nothing (256 MiB at most)
_MARGIN = 1e-3  # metres of slack in the clearance, far above float32 rounding


def cell_candidate_table(start: np.ndarray, delta: np.ndarray, side: float = CELL_SIDE,
                         k: int = CELL_CANDIDATES) -> dict:
    """A planar grid over the segments: per cell, the `k` segments nearest its centre, and a clearance.

    The clearance is a lower bound of the planar distance from any point of the cell to every
    segment not listed. The selection distance of `segment_distances` is at least the planar
    distance, so a query whose nearest listed segment is nearer than the clearance has found the
    nearest of all, ties included (a tie outside would be nearer than the clearance). Queries
    outside the grid or beyond the clearance are for an exhaustive search; so are all of them for a
    map too large for a grid of at most `_MAX_CELLS` cells (`unsettling_cell_table`).

    Bounds (`_cell_table`): the listed segments are the `k` nearest the centre, found exactly among
    those its group of cells gathered, and the clearance is the next one's distance (or what the
    group left out can reach, if nearer) less the cell's half-diagonal and a slack far above
    float32 rounding.

    Args:
      start, delta: float32 `(num_segments, 3)`, the segments the indices refer to (all valid).
    Returns:
      origin float32 `(2,)`, shape int32 `(2,)` (cells along x, y), candidates int32
      `(num_cells, k)` (cell `ix * shape[1] + iy`; rows with fewer segments repeat their first),
      clearance float32 `(num_cells,)`.
    """
    start, delta = np.ascontiguousarray(start, _F), np.ascontiguousarray(delta, _F)
    start64, delta64 = start[:, :2].astype(np.float64), delta[:, :2].astype(np.float64)
    low, high = column_bounds(np.concatenate([start64, start64 + delta64]))
    origin = np.floor(low - _CELL_BORDER)
    shape = np.ceil((high + _CELL_BORDER - origin) / side).astype(np.int64)
    if not np.isfinite(origin).all() or shape[0] * shape[1] > _MAX_CELLS:
        return unsettling_cell_table(k)  # every query searches all segments: exact, slower
    buckets = _bucket_grid(start, delta, np.ones(len(start), bool))
    grid = (*(float(v) for v in buckets["bucket_origin"]), float(buckets["bucket_side"]),
            *(int(v) for v in buckets["bucket_shape"]), *(int(v) for v in buckets["segment_buckets"]))
    candidates, clearance = _cell_table(_frames(start, delta), float(origin[0]), float(origin[1]), int(shape[0]),
                                        int(shape[1]), float(side), int(k), grid, buckets["bucket_start"],
                                        buckets["bucket_segments"])
    return {"origin": origin.astype(_F), "shape": shape.astype(np.int32), "candidates": candidates,
            "clearance": clearance.astype(_F)}


def unsettling_cell_table(k: int = CELL_CANDIDATES) -> dict:
    """A `cell_candidate_table` of one cell that settles no query (a clearance of -inf)."""
    return {"origin": np.zeros(2, _F), "shape": np.ones(2, np.int32), "candidates": np.zeros((1, k), np.int32),
            "clearance": np.full(1, -np.inf, _F)}


@numba.njit(cache=True, error_model="numpy")
def _cell_table(frame, origin_x, origin_y, num_x, num_y, side, k, grid, bucket_start, bucket_segments):
    """`cell_candidate_table`'s lists and clearances (float64), group of cells by group.

    A group of `_GROUP_CELLS` x `_GROUP_CELLS` cells gathers, ring by ring of buckets around its
    centre b, every segment within L = D(b) + 2h, where D(x) is the planar distance from x to
    its (k+1)-th nearest segment and h the group's half-diagonal; unseen segments are farther
    than L (the rings stop past it). A segment's distances from b and from a cell centre c differ
    by at most s = |c - b| <= h, so D(c) <= D(b) + s: the k+1 nearest of c are among the gathered
    segments within D(b) + 2s of b, and every other segment is at least D(c) from c, or beyond
    L - s if never gathered.
    """
    num_segments = frame.shape[0]
    bucket_side = grid[2]
    candidates = np.empty((num_x * num_y, max(k, 1)), np.int32)
    clearance = np.empty(num_x * num_y, np.float64)
    seen = np.full(num_segments, -1, np.int64)
    ring = _ring_buffer(grid)
    gathered = np.empty(num_segments, np.int32)
    gathered_distance = np.empty(num_segments, np.float64)
    squared = np.empty(num_segments, np.float64)
    half_diagonal = side * math.sqrt(0.5)
    group_half = _GROUP_CELLS * half_diagonal
    tag = 0
    for gx in range(0, num_x, _GROUP_CELLS):
        for gy in range(0, num_y, _GROUP_CELLS):
            bx = origin_x + (gx + 0.5 * _GROUP_CELLS) * side
            by = origin_y + (gy + 0.5 * _GROUP_CELLS) * side
            # The segments around the group's centre by rings of buckets, until L is passed.
            bi, bj, first, last = _rings_around(bx, by, grid)
            m, nearest_beyond = 0, np.inf  # D(b)
            for r in range(first, last + 1):
                if r > first and (r - 1) * bucket_side > nearest_beyond + 2.0 * group_half:
                    break  # every segment not met yet is at least (r - 1) * bucket_side away
                m = _gather_ring(bx, by, bi, bj, r, frame, grid, bucket_start, bucket_segments, seen, tag, ring,
                                 gathered, gathered_distance, m)
                if m > k:
                    nearest_beyond = np.partition(gathered_distance[:m], k)[k]
            tag += 1
            order = np.argsort(gathered_distance[:m])
            group, group_distance = gathered[:m][order], gathered_distance[:m][order]
            for cx in range(gx, min(gx + _GROUP_CELLS, num_x)):
                for cy in range(gy, min(gy + _GROUP_CELLS, num_y)):
                    row = cx * num_y + cy
                    px, py = origin_x + (cx + 0.5) * side, origin_y + (cy + 0.5) * side
                    shift = math.hypot(px - bx, py - by)
                    kept = np.searchsorted(group_distance, nearest_beyond + 2.0 * shift, side="right")
                    for p in range(kept):
                        squared[p] = _planar_squared(px, py, group[p], frame)
                    beyond = np.inf  # the squared D(c)
                    if kept > k:
                        beyond = np.partition(squared[:kept], k)[k]
                    listed = 0
                    for p in range(kept):  # the k nearest: those nearer than the (k+1)-th, then ties
                        if squared[p] < beyond:
                            candidates[row, listed] = group[p]
                            listed += 1
                    for p in range(kept):
                        if listed >= k:
                            break
                        if squared[p] == beyond:
                            candidates[row, listed] = group[p]
                            listed += 1
                    for p in range(listed, candidates.shape[1]):
                        candidates[row, p] = candidates[row, 0] if listed else 0
                    never_gathered = nearest_beyond + 2.0 * group_half - shift
                    slack = _MARGIN + 1e-5 * max(abs(px), abs(py))
                    clearance[row] = min(math.sqrt(beyond), never_gathered) - half_diagonal - slack
    return candidates, clearance
