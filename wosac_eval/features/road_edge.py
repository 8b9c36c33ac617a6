"""Signed distance from box corners to the road edge; offroad.

Road edges are polylines with the road on their left. For each query point the
relevant segment is the nearest one in 3D, with heights stretched 3x so that a
road edge on another level (a bridge) is not picked; the returned distance is
the planar distance to that segment, negative on the road side. Where the
point projects past a segment end, the sign follows the convexity of the
corner between the segment and its neighbour.

Segment search groups the query points in 1 m cells, finds each cell's
candidate segments with a k-d tree over points along every segment, narrows
them per point with a distance bound (one `searchsorted` in the cell's
candidates sorted by distance), then evaluates the exact float32 distance on
the few survivors; the bounds are proven, so results equal an all-pairs
search (tests compare with brute force, steep ramps included).
"""
from __future__ import annotations

import dataclasses
import itertools

import numpy as np
from scipy.spatial import cKDTree

from wosac_eval.features.spatial import non_finite_pick, pad_polylines
from wosac_eval.features.xp import array_namespace, divide, errstate


_F = np.float32
EXTREMELY_LARGE_DISTANCE = _F(1e10)
OFFROAD_DISTANCE_THRESHOLD = 0.0
Z_STRETCH = 3.0
CYCLIC_TOLERANCE_M2 = 1.0
_SAMPLE_SPACING = 1.0  # metres between candidate-search samples along a segment


@dataclasses.dataclass(frozen=True)
class SegmentTable:
    """Road-edge segments flattened in the official (polyline, segment) order.

    Polylines are padded to the longest one, as the official code does; padding
    segments are invalid. Attributes are `(num_segments,)` or `(num_segments, 3)`.
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
    columns: np.ndarray      # float32 (6, S): start x, y, z, delta x, y, z, contiguous for gathers
    squared: np.ndarray      # float32 (S,): dx * dx + dy * dy, as `segment_distances` computes it
    columns64: np.ndarray    # float64 (6, S): the same with heights stretched, for the search bounds
    lipschitz: np.ndarray    # float64 (S,): how fast the selection distance can change with the point
    max_lipschitz: float
    tree: cKDTree | None
    sample_segment: np.ndarray  # int64: segment of each k-d tree sample
    spacing: float


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def build_segment_table(polylines) -> SegmentTable:
    """Pads polylines to a common length and precomputes segment neighbours.

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
    tree, sample_segment = _sample_tree(start.reshape(-1, 3), delta.reshape(-1, 3), valid_flat)
    lipschitz = _lipschitz(delta.reshape(-1, 3))
    return SegmentTable(
        start=start.reshape(-1, 3), delta=delta.reshape(-1, 3), valid=valid_flat,
        prior=prior, next=nxt, prior_valid=valid_flat[prior], next_valid=valid_flat[nxt],
        convex_before=convex_before.reshape(-1), convex_after=convex_after.reshape(-1),
        columns=np.ascontiguousarray(np.concatenate([start.reshape(-1, 3), delta.reshape(-1, 3)], axis=1).T),
        squared=delta[..., 0].reshape(-1) * delta[..., 0].reshape(-1) + delta[..., 1].reshape(-1) * delta[..., 1].reshape(-1),
        columns64=np.ascontiguousarray(np.concatenate([_stretch(start.reshape(-1, 3)),
                                                       _stretch(delta.reshape(-1, 3))], axis=1).T),
        lipschitz=lipschitz, max_lipschitz=float(lipschitz[valid_flat].max(initial=1.0)),
        tree=tree, sample_segment=sample_segment, spacing=_SAMPLE_SPACING)


def _stretch(xyz):
    out = np.asarray(xyz, np.float64).copy()
    out[..., 2] *= Z_STRETCH
    return out


def _lipschitz(delta: np.ndarray) -> np.ndarray:
    """Per segment, the most the selection distance changes per metre the point moves.

    The projection is planar, so a point moving by v shifts the projected
    point along the segment by v's along-track part times the segment's
    stretched slope s = 3|dz| / |d_xy|: the offset changes by at most
    sqrt(1 + s^2) |v| (1 for segments without planar length, whose projection
    is pinned at the start). Used by the candidate search only, with margin.
    """
    d = _stretch(delta)
    planar = np.hypot(d[:, 0], d[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.where(planar > 0, np.abs(d[:, 2]) / planar, 0.0)
    return np.sqrt(1.0 + slope * slope) * (1 + 1e-6)


def _sample_tree(start, delta, valid):
    """k-d tree over valid segments cut in pieces of at most `_SAMPLE_SPACING` (stretched) metres.

    The tree holds each piece's midpoint, so every point of a segment is within
    half the spacing of one of its tree points; points are numbered along the
    segments in segment order.
    """
    idx = np.flatnonzero(valid)
    if idx.size == 0:
        return None, np.zeros(0, np.int64)
    points, seg_of = _piece_midpoints(_stretch(start[idx]), _stretch(delta[idx]))
    return cKDTree(points), idx[seg_of]


def _piece_midpoints(start, delta):
    """Segments cut in pieces of at most `_SAMPLE_SPACING` metres (in their own coordinates):
    (the pieces' midpoints `(num_pieces, d)`, the segment of each), numbered along the segments."""
    length = np.linalg.norm(delta, axis=-1)
    count = np.maximum(1, np.ceil(length / _SAMPLE_SPACING).astype(np.int64))
    seg_of = np.repeat(np.arange(len(start)), count)
    first = np.repeat(np.cumsum(count) - count, count)
    frac = (np.arange(seg_of.size) - first + 0.5) / np.repeat(count, count)
    return start[seg_of] + delta[seg_of] * frac[:, None], seg_of


def segment_distances(px, py, pz, sx, sy, sz, dx, dy, dz):
    """Projection parameter, stretched 3D distance and planar distance, float32.

    Elementwise (broadcasting) over points p, segment starts s and segment
    vectors d, in the official order of float32 operations (numpy or JAX arrays).
    """
    xp = array_namespace(px, sx)
    tx, ty, tz = px - sx, py - sy, pz - sz
    along = tx * dx + ty * dy
    squared = dx * dx + dy * dy
    with errstate(xp, divide="ignore", invalid="ignore"):
        rel_t = xp.where(squared == 0, _F(0), divide(along, squared))
    clipped = xp.clip(rel_t, _F(0), _F(1))
    ox, oy = tx - dx * clipped, ty - dy * clipped
    oz = (tz - dz * clipped) * _F(Z_STRETCH)
    planar2 = ox * ox + oy * oy
    return rel_t, xp.sqrt(planar2 + oz * oz), xp.sqrt(planar2)


def _pair_distances(table: SegmentTable, query_columns: np.ndarray, qi, si: np.ndarray):
    """`segment_distances` for (query, segment) pairs, gathering one column at a time.

    Args:
      query_columns: float32 `(3, num_points)`.
      qi: the query of each pair, or None when pair i is query i.
      si: int `(num_pairs,)`, the segment of each pair.
    """
    p = query_columns if qi is None else [np.take(c, qi) for c in query_columns]
    seg = [np.take(c, si) for c in table.columns]
    return segment_distances(*p, *seg)


# Pairs per block of `_selection_distances`: the working arrays stay in the CPU cache.
_PAIR_BLOCK = 1 << 15


def _selection_distances(table: SegmentTable, query_columns: np.ndarray, qi: np.ndarray, si: np.ndarray):
    """The stretched 3D distance of `segment_distances` for (query, segment) pairs, float32 `(num_pairs,)`.

    The same float32 operations, in blocks of `_PAIR_BLOCK` pairs computed in
    place (the squared segment length comes from the table), which keeps the
    candidate evaluation, most of the road-edge time, in the cache.
    """
    n = len(qi)
    out = np.empty(n, _F)
    px, py, pz = query_columns
    sx, sy, sz, dx, dy, dz = table.columns
    buf = np.empty((8, min(n, _PAIR_BLOCK)), _F)
    with np.errstate(divide="ignore", invalid="ignore"):
        for lo in range(0, n, _PAIR_BLOCK):
            q, s = qi[lo:lo + _PAIR_BLOCK], si[lo:lo + _PAIR_BLOCK]
            m = len(q)
            tx, ty, tz, ax, ay, az, rel, tmp = (b[:m] for b in buf)
            np.subtract(np.take(px, q), np.take(sx, s), out=tx)
            np.subtract(np.take(py, q), np.take(sy, s), out=ty)
            np.subtract(np.take(pz, q), np.take(sz, s), out=tz)
            np.take(dx, s, out=ax)
            np.take(dy, s, out=ay)
            np.take(dz, s, out=az)
            np.multiply(tx, ax, out=rel)
            np.multiply(ty, ay, out=tmp)
            rel += tmp                                   # along = tx dx + ty dy
            squared = np.take(table.squared, s)
            np.divide(rel, squared, out=rel)
            rel[squared == 0] = 0
            np.clip(rel, _F(0), _F(1), out=rel)          # the clipped projection
            tx -= np.multiply(ax, rel, out=tmp)          # ox
            ty -= np.multiply(ay, rel, out=tmp)          # oy
            tz -= np.multiply(az, rel, out=tmp)
            tz *= _F(Z_STRETCH)                          # oz
            tx *= tx
            ty *= ty
            tx += ty                                     # planar2
            tz *= tz
            tx += tz
            np.sqrt(tx, out=out[lo:lo + m])
    return out


_CELL = 1.0  # metres: queries are grouped in cubic cells of the stretched space
_MARGIN = 1e-3  # metres of slack in every float64 bound, far above float32 rounding


def _segment_distance64(table: SegmentTable, points: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Stretched 3D selection distance from stretched points `(3, n)` to segments, float64 (bounds only)."""
    sx, sy, sz, dx, dy, dz = (np.take(c, seg) for c in table.columns64)
    tx, ty, tz = points[0] - sx, points[1] - sy, points[2] - sz
    squared = dx * dx + dy * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip(np.where(squared > 0, (tx * dx + ty * dy) / squared, 0.0), 0.0, 1.0)
    tx -= dx * t
    ty -= dy * t
    tz -= dz * t
    return np.sqrt(tx * tx + ty * ty + tz * tz)


def _ball_pairs(tree: cKDTree, centres: np.ndarray, radius: np.ndarray):
    """(centre index, tree point) pairs within `radius` of each centre, sorted by centre."""
    lists = tree.query_ball_point(centres, radius, return_sorted=True)
    sizes = np.fromiter(map(len, lists), np.int64, len(lists))
    points = np.fromiter(itertools.chain.from_iterable(lists), np.int64, int(sizes.sum()))
    return np.repeat(np.arange(len(centres)), sizes), points


def _argsort(key: np.ndarray, num_keys: int) -> tuple[np.ndarray, np.ndarray]:
    """(order, sorted keys) of non-negative int64 keys below `num_keys`.

    Sorts (key, position) packed in one integer: numpy's vectorised `sort` is
    several times faster than `argsort` (any order of equal keys will do here).
    """
    bits = max(1, len(key).bit_length())
    if num_keys >= 1 << (62 - bits):
        order = np.argsort(key)
        return order, key[order]
    packed = np.sort((key << bits) | np.arange(len(key), dtype=np.int64))
    return packed & ((1 << bits) - 1), packed >> bits


# Cells of margin kept around the map's box when numbering cells densely (`_cells_of`).
_CORE_MARGIN_CELLS = 32


def _cells_of(points_t: np.ndarray, core: tuple[np.ndarray, np.ndarray] | None = None):
    """The cubic cells of side `_CELL` holding the points.

    Args:
      points_t: float64 `(3, num_points)`.
      core: optional (low, high) float64 `(3,)` corners of the box where most points lie (the
        map's, with a margin). Points outside it (placeholder states far from the map) are grouped
        apart: they would otherwise stretch the key space from a dense count to a sort of every key.
    Returns:
      (number of occupied cells, int64 `(num_points,)` cell of each point
      numbered in key order, int64 `(num_points,)` the points sorted by cell).
    """
    cell = np.floor(points_t / _CELL).astype(np.int64)
    if core is None:
        return _group_cells(cell)
    core_low = np.floor(core[0] / _CELL).astype(np.int64) - _CORE_MARGIN_CELLS
    core_high = np.floor(core[1] / _CELL).astype(np.int64) + _CORE_MARGIN_CELLS
    inside = np.ones(cell.shape[1], bool)
    for axis in range(3):  # row by row: a reduction over the short axis is slow
        inside &= cell[axis] >= core_low[axis]
        inside &= cell[axis] <= core_high[axis]
    if inside.all() or not inside.any():
        return _group_cells(cell)
    # One key space, without copying the points inside: theirs dense in their own box, then the
    # cells outside, numbered among themselves.
    big = np.iinfo(np.int64).max
    low = np.array([row.min(where=inside, initial=big) for row in cell])
    high = np.array([row.max(where=inside, initial=-big) for row in cell])
    key, num_keys = _dense_keys(cell, low, high)
    outside = np.flatnonzero(~inside)
    far_cells, far_inverse, _ = _group_cells(cell[:, outside])
    key[outside] = num_keys + far_inverse
    return _group_keys(key, num_keys + far_cells)


def _dense_keys(cell: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, int]:
    """Keys of integer cells `(3, num_points)` in the box [low, high] numbered x-major, and their count."""
    span = high - low + 1
    key = ((cell[0] - low[0]) * span[1] + (cell[1] - low[1])) * span[2] + (cell[2] - low[2])
    return key, int(np.prod(span, dtype=np.float64))


def _group_cells(cell: np.ndarray):
    """`_cells_of` for integer cells `(3, num_points)`."""
    low = np.array([row.min() for row in cell])
    high = np.array([row.max() for row in cell])
    return _group_keys(*_dense_keys(cell, low, high))


def _group_keys(key: np.ndarray, num_keys: int):
    """`_cells_of` for non-negative int64 keys below `num_keys`, one per cell."""
    if num_keys <= 16 * len(key):  # a small box: count occupied keys instead of sorting
        occupied = np.bincount(key, minlength=num_keys) > 0
        num_cells = int(occupied.sum())
        inverse = (np.cumsum(occupied) - 1)[key]
        # Few cells: a stable sort of small integers is a radix sort.
        small = np.uint16 if num_cells <= 1 << 16 else np.uint32
        return num_cells, inverse, np.argsort(inverse.astype(small), kind="stable")
    order, sorted_key = _argsort(key, num_keys)
    first = np.r_[True, sorted_key[1:] != sorted_key[:-1]]
    inverse = np.empty(len(key), np.int64)
    inverse[order] = np.cumsum(first) - 1
    return int(first.sum()), inverse, order


def _candidates(table: SegmentTable, queries: np.ndarray):
    """(query index, segment index) pairs that include every possible nearest segment.

    Returns (qi, si, starts): pairs grouped by query, every query has at least
    one, and `starts[i]` is the first pair of query i.

    The selection distance D(k, p) projects p on segment k in the plane, then
    measures the stretched 3D offset; it moves by at most L_k |p - q| between
    points p and q (`SegmentTable.lipschitz`). Queries are grouped in cells of
    side `_CELL`; a cell is represented by the centroid c of its queries and
    the largest distance h from c to one of them:
      - any segment j bounds the cell's minimum: D(j, p) <= D(j, c) + L_j h = U_j;
      - a segment k can only be nearest somewhere in the cell if
        D(k, c) - L_k h <= min_j U_j, and D(k, c) is at least the distance from c
        to k's nearest k-d tree point minus half the spacing, which bounds
        the k-d tree search;
      - for one query p at distance r from c, with b = D(cell's first candidate, p),
        k can only win if D(k, c) <= b + L_max r, a cut made with one
        `searchsorted` in the cell's candidates sorted by D(k, c).
    Float32 results then pick the nearest among the survivors exactly.
    """
    q = _stretch(queries)
    qt = np.ascontiguousarray(q.T)
    num_cells, inverse, by_cell = _cells_of(qt, (table.tree.mins, table.tree.maxes))
    # Each cell is represented by the centroid of its queries and the largest
    # distance from it to one of them (at most the cell's half-diagonal).
    count = np.bincount(inverse, minlength=num_cells).astype(np.float64)
    centre = np.stack([np.bincount(inverse, weights=qt[k], minlength=num_cells) for k in range(3)], axis=1)
    centre /= count[:, None]
    r = np.zeros(len(q))
    for axis in range(3):  # row by row: a reduction over the short axis is slow
        offset = qt[axis] - np.take(centre[:, axis], inverse)
        offset *= offset
        r += offset
    np.sqrt(r, out=r)
    h_cell = np.zeros(num_cells)
    np.maximum.at(h_cell, inverse, r)
    h_cell += 1e-9
    lipschitz = table.lipschitz
    # An upper bound of each cell's minimum from the segment of its nearest sample.
    _, nearest_sample = table.tree.query(centre, k=1)
    first_guess = table.sample_segment[nearest_sample]
    centre_t = np.ascontiguousarray(centre.T)
    upper = _segment_distance64(table, centre_t, first_guess) + lipschitz[first_guess] * h_cell
    radius = upper + table.max_lipschitz * h_cell + table.spacing * 0.5 + _MARGIN * (1 + upper)
    ci, sample = _ball_pairs(table.tree, centre, radius)
    # Pairs come sorted by cell, then sample, and samples are numbered along
    # the segments, so repeated (cell, segment) pairs are adjacent.
    seg = table.sample_segment[sample]
    new = np.r_[True, (ci[1:] != ci[:-1]) | (seg[1:] != seg[:-1])]
    ci, seg = ci[new], seg[new]
    d = _segment_distance64(table, centre_t[:, ci], seg)
    best_upper = np.full(num_cells, np.inf)
    np.minimum.at(best_upper, ci, d + lipschitz[seg] * h_cell[ci])
    keep = d - lipschitz[seg] * h_cell[ci] <= best_upper[ci] + _MARGIN * (1 + best_upper[ci])
    ci, seg, d = ci[keep], seg[keep], d[keep]
    # Each cell's candidates sorted by distance to its centre, under one key:
    # the cell index times a stride above any distance or limit below.
    stride = 2.0 * (d.max() + 2 * table.max_lipschitz * h_cell.max()) + 1.0
    key = ci * stride + d
    order = np.argsort(key)
    key, seg = key[order], seg[order]
    first = np.searchsorted(ci, np.arange(num_cells))  # ci is sorted already
    cell_lipschitz = np.maximum.reduceat(lipschitz[seg], first)
    bound = _segment_distance64(table, qt, seg[first][inverse])
    limit = bound + cell_lipschitz[inverse] * r + _MARGIN * (1 + bound)
    lo = first[inverse]
    # The cut, searched with the queries in cell order (the searches then move forward in `key`).
    hi = np.empty(len(q), np.int64)
    hi[by_cell] = np.searchsorted(key, (inverse * stride + limit)[by_cell], side="right")
    count = hi - lo
    if count.min(initial=1) < 1:  # impossible by the bounds above; a bug if it happens
        raise RuntimeError("road-edge candidate search left a query without candidates")
    qi = np.repeat(np.arange(len(q)), count)
    starts = np.cumsum(count) - count
    pos = np.arange(qi.size) - np.repeat(starts - lo, count)
    return qi, seg[pos], starts


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
    """`segment_side` on separate coordinates (elementwise, broadcasting)."""
    return array_namespace(px, sx).sign(_cross(px - sx, py - sy, dx, dy))


def corner_sign(rel_t, n, n_prior, n_next, convex_before, convex_after, prior_valid, next_valid):
    """Side of the nearest segment, corrected where the point projects past an end.

    Past an end the sign follows the corner with the neighbour segment: on a
    convex corner the point is off-road if it is on the right of either
    segment, on a concave one only if it is on the right of both.
    All arguments are `(...)` arrays (numpy or JAX).
    """
    xp = array_namespace(rel_t, n)
    before = xp.where(convex_before, xp.maximum(n, n_prior), xp.minimum(n, n_prior))
    after = xp.where(convex_after, xp.maximum(n, n_next), xp.minimum(n, n_next))
    return xp.where((rel_t < 0) & prior_valid, before,
                    xp.where((rel_t > 1) & next_valid, after, n))


def _side(table: SegmentTable, qx, qy, seg):
    """`segment_side` of points `(n,)` against table segments `(n,)`, gathering one column at a time."""
    sx, sy, _, dx, dy, _ = (np.take(c, seg) for c in table.columns)
    return side_of_segment(qx, qy, sx, sy, dx, dy)


def signed_distance_to_polylines(table: SegmentTable, queries: np.ndarray) -> np.ndarray:
    """Signed planar distance from points to the road-edge boundary.

    Args:
      table: the road edges, from `build_segment_table`.
      queries: float32 `(num_points, 3)`.
    Returns:
      float32 `(num_points,)`, negative on the road side.
    """
    queries = np.asarray(queries, _F)
    if len(queries) == 0:
        return np.zeros(0, _F)
    finite = np.isfinite(queries)
    finite = finite[:, 0] & finite[:, 1] & finite[:, 2]  # faster than a reduction over the short axis
    bs = np.full(len(queries), non_finite_pick(table.valid), np.int64)
    if finite.any():
        searched = queries if finite.all() else queries[finite]
        qi, si, starts = _candidates(table, searched)
        d3 = _selection_distances(table, np.ascontiguousarray(searched.T), qi, si)
        # Nearest in 3D, ties to the lowest segment index, in one integer minimum:
        # non-negative float32 values order like their bit patterns.
        key = (d3.view(np.int32).astype(np.int64) << 32) | si
        bs[finite] = np.minimum.reduceat(key, starts) & 0xFFFFFFFF  # one per query, in order
    columns = np.ascontiguousarray(queries.T)
    with np.errstate(invalid="ignore", over="ignore"):
        bt, _, d2 = _pair_distances(table, columns, None, bs)
        qx, qy = columns[0], columns[1]
        n = _side(table, qx, qy, bs)
        prior_valid, next_valid = table.prior_valid[bs], table.next_valid[bs]
        # The neighbours' sides only where `corner_sign` reads them (past an end: ~15% of queries).
        n_prior, n_next = n.copy(), n.copy()
        for side, past, neighbour in ((n_prior, (bt < 0) & prior_valid, table.prior),
                                      (n_next, (bt > 1) & next_valid, table.next)):
            i = np.flatnonzero(past)
            side[i] = _side(table, qx[i], qy[i], neighbour[bs[i]])
    sign = corner_sign(bt, n, n_prior, n_next, table.convex_before[bs], table.convex_after[bs],
                       prior_valid, next_valid)
    # A padding segment's distance is 1e10, as officially (only non-finite points get one).
    return (sign * np.where(table.valid[bs], d2, EXTREMELY_LARGE_DISTANCE)).astype(_F)


def distance_to_road_edge(corners_xyz: np.ndarray, valid: np.ndarray, table: SegmentTable) -> np.ndarray:
    """Signed distance of the most off-road corner of each box.

    Args:
      corners_xyz: float32 `(..., num_objects, num_steps, 4, 3)` bottom corners.
      valid: bool `(..., num_objects, num_steps)`.
    Returns:
      float32 `(..., num_objects, num_steps)`; -1e10 where invalid.
    """
    # Only valid boxes are searched: invalid log states sit at placeholder
    # positions (often the origin, kilometres from the map) and are masked anyway.
    boxes = corners_xyz.reshape(-1, 4, 3)
    keep = np.flatnonzero(np.broadcast_to(valid, corners_xyz.shape[:-2]).reshape(-1))
    out = np.full(len(boxes), -EXTREMELY_LARGE_DISTANCE, _F)
    distance = signed_distance_to_polylines(table, boxes[keep].reshape(-1, 3)).reshape(-1, 4)
    out[keep] = distance.max(axis=-1)
    return out.reshape(corners_xyz.shape[:-2])


# --- Cell tables for fixed-shape searches (the JAX driver, features/dense.py) ----------------------

CELL_SIDE = 4.0  # metres: the planar grid of the candidate tables
CELL_CANDIDATES = 32  # segments listed per cell
_CELL_BORDER = 10.0  # metres of grid around the segments' box
_TABLE_SAMPLES = 4  # k-d tree samples looked at per listed segment


def cell_candidate_table(start: np.ndarray, delta: np.ndarray, side: float = CELL_SIDE,
                         k: int = CELL_CANDIDATES) -> dict:
    """A planar grid over the segments: per cell, the `k` segments nearest its centre, and a clearance.

    The clearance is a lower bound of the planar distance from any point of the cell to every
    segment not listed. The selection distance of `segment_distances` is at least the planar
    distance, so a query whose nearest listed segment is nearer than the clearance has found the
    nearest of all, ties included (a tie outside would be nearer than the clearance). Queries
    outside the grid or beyond the clearance are for an exhaustive search.

    Bounds: a segment is cut in planar pieces of at most `_SAMPLE_SPACING` metres, whose midpoints
    form a k-d tree, so every point of it is within half the spacing of a sample. A segment with no
    sample among a centre's nearest ones is at least (farthest of those) - spacing / 2 from it; one
    found but not listed at least the (k+1)-th listed distance. The cell's half-diagonal, and a
    slack far above float32 rounding, are subtracted.

    Args:
      start, delta: float32 `(num_segments, 3)`, the segments the indices refer to (all valid).
    Returns:
      origin float32 `(2,)`, shape int32 `(2,)` (cells along x, y), candidates int32
      `(num_cells, k)` (cell `ix * shape[1] + iy`; rows with fewer segments repeat their first),
      clearance float32 `(num_cells,)`.
    """
    start64, delta64 = np.asarray(start, np.float64)[:, :2], np.asarray(delta, np.float64)[:, :2]
    ends = np.concatenate([start64, start64 + delta64])
    origin = np.floor(ends.min(axis=0) - _CELL_BORDER)
    shape = np.ceil((ends.max(axis=0) + _CELL_BORDER - origin) / side).astype(np.int64)
    ix, iy = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    centre = origin + (np.stack([ix.ravel(), iy.ravel()], axis=1) + 0.5) * side
    samples, seg_of = _piece_midpoints(start64, delta64)
    kk = min(_TABLE_SAMPLES * k, len(samples))
    reach, nearest = cKDTree(samples).query(centre, k=kk)
    reach, nearest = reach.reshape(len(centre), kk), nearest.reshape(len(centre), kk)
    seg = seg_of[nearest]
    # Planar distance from each centre to each found segment (float64), repeats set apart.
    sx, sy = start64[seg, 0], start64[seg, 1]
    dx, dy = delta64[seg, 0], delta64[seg, 1]
    tx, ty = centre[:, None, 0] - sx, centre[:, None, 1] - sy
    squared = dx * dx + dy * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip(np.where(squared > 0, (tx * dx + ty * dy) / squared, 0.0), 0.0, 1.0)
    dist = np.hypot(tx - dx * t, ty - dy * t)
    by_seg = np.argsort(seg, axis=1, kind="stable")
    sorted_seg = np.take_along_axis(seg, by_seg, axis=1)
    repeat = np.zeros_like(sorted_seg, bool)
    repeat[:, 1:] = sorted_seg[:, 1:] == sorted_seg[:, :-1]
    dist_sorted = np.where(repeat, np.inf, np.take_along_axis(dist, by_seg, axis=1))
    order = np.argsort(dist_sorted, axis=1, kind="stable")
    listed = np.take_along_axis(sorted_seg, order, axis=1)
    listed_dist = np.take_along_axis(dist_sorted, order, axis=1)
    take = min(k, kk)
    candidates = listed[:, :take]
    found = np.isfinite(listed_dist[:, :take])
    candidates = np.where(found, candidates, candidates[:, :1])
    if take < k:
        candidates = np.concatenate([candidates, np.repeat(candidates[:, :1], k - take, axis=1)], axis=1)
    next_listed = listed_dist[:, take] if kk > take else np.full(len(centre), np.inf)
    unseen = reach[:, -1] - 0.5 * _SAMPLE_SPACING if kk < len(samples) else np.full(len(centre), np.inf)
    half_diagonal = side * np.sqrt(0.5)
    slack = _MARGIN + 1e-5 * np.abs(centre).max(axis=1)
    clearance = np.minimum(next_listed, unseen) - half_diagonal - slack
    return {"origin": origin.astype(_F), "shape": shape.astype(np.int32),
            "candidates": candidates.astype(np.int32), "clearance": clearance.astype(_F)}
