"""Signed distance from box corners to the road edge; offroad.

Road edges are polylines with the road on their left. For each query point the
relevant segment is the nearest one in 3D, with heights stretched 3x so that a
road edge on another level (a bridge) is not picked; the returned distance is
the planar distance to that segment, negative on the road side. Where the
point projects past a segment end, the sign follows the convexity of the
corner between the segment and its neighbour.

Segment search groups the query points in 1 m cells, finds each cell's
candidate segments with a k-d tree over points sampled along every segment,
narrows them per point with a distance bound, then evaluates the exact float32
distance on the few remaining candidates, so results equal an all-pairs search.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from wosac_eval.features.spatial import first_minimum, tree_candidates
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
    padded = np.zeros((len(kept), num_points, 3), _F)
    point_valid = np.zeros((len(kept), num_points), bool)
    cyclic = np.zeros(len(kept), bool)
    for i, p in enumerate(kept):
        padded[i, : len(p)] = p
        point_valid[i, : len(p)] = True
        gap = p[0] - p[-1]
        cyclic[i] = np.sum(gap * gap, dtype=_F) < _F(CYCLIC_TOLERANCE_M2)
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
    return SegmentTable(
        start=start.reshape(-1, 3), delta=delta.reshape(-1, 3), valid=valid_flat,
        prior=prior, next=nxt, prior_valid=valid_flat[prior], next_valid=valid_flat[nxt],
        convex_before=convex_before.reshape(-1), convex_after=convex_after.reshape(-1),
        tree=tree, sample_segment=sample_segment, spacing=_SAMPLE_SPACING)


def _stretch(xyz):
    out = np.asarray(xyz, np.float64).copy()
    out[..., 2] *= Z_STRETCH
    return out


def _sample_tree(start, delta, valid):
    """k-d tree over points every `_SAMPLE_SPACING` metres along valid segments."""
    idx = np.flatnonzero(valid)
    if idx.size == 0:
        return None, np.zeros(0, np.int64)
    s = _stretch(start[idx])
    d = _stretch(delta[idx])
    length = np.linalg.norm(d, axis=-1)
    count = np.maximum(1, np.ceil(length / _SAMPLE_SPACING).astype(np.int64)) + 1
    seg_of = np.repeat(np.arange(idx.size), count)
    first = np.repeat(np.cumsum(count) - count, count)
    frac = (np.arange(seg_of.size) - first) / np.repeat(count - 1, count)
    points = s[seg_of] + d[seg_of] * frac[:, None]
    return cKDTree(points), idx[seg_of]


def segment_pair_distances(query, start, delta):
    """Projection parameter, stretched 3D distance and planar distance, float32, per pair.

    Args:
      query, start, delta: float32 `(..., 3)`, broadcast against each other
        (numpy or JAX arrays).
    Returns:
      (rel_t, distance_3d, distance_2d), float32 `(...)`.
    """
    xp = array_namespace(query, start, delta)
    to_point = query - start
    along = to_point[..., 0] * delta[..., 0] + to_point[..., 1] * delta[..., 1]
    squared = delta[..., 0] * delta[..., 0] + delta[..., 1] * delta[..., 1]
    with errstate(xp, divide="ignore", invalid="ignore"):
        rel_t = xp.where(squared == 0, _F(0), divide(along, squared))
    clipped = xp.clip(rel_t, _F(0), _F(1))
    offset = to_point - delta * clipped[..., None]
    oz = offset[..., 2] * _F(Z_STRETCH)
    planar2 = offset[..., 0] * offset[..., 0] + offset[..., 1] * offset[..., 1]
    return rel_t, xp.sqrt(planar2 + oz * oz), xp.sqrt(planar2)


def _segment_distances(table: SegmentTable, queries: np.ndarray, qi: np.ndarray, si: np.ndarray):
    """`segment_pair_distances` for (query index, segment index) pairs."""
    return segment_pair_distances(queries[qi], table.start[si], table.delta[si])


_CELL = 1.0  # metres: queries are grouped in cubic cells of the stretched space


def _segment_distance64(table: SegmentTable, points: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Stretched 3D distance from stretched points to segments, in float64 (for bounds only)."""
    start = _stretch(table.start[seg])
    delta = _stretch(table.delta[seg])
    rel = points - start
    squared = np.einsum("ij,ij->i", delta[:, :2], delta[:, :2])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(squared > 0, np.einsum("ij,ij->i", rel[:, :2], delta[:, :2]) / squared, 0.0)
    offset = rel - delta * np.clip(t, 0.0, 1.0)[:, None]
    return np.sqrt(np.einsum("ij,ij->i", offset, offset))


def _candidates(table: SegmentTable, queries: np.ndarray):
    """(query index, segment index) pairs that include every possible nearest segment.

    Queries are grouped in cells of side `_CELL` (half-diagonal h). For a
    query p in a cell with centre c, the nearest segment k* satisfies
    D(k*, c) <= D(k*, p) + h <= D(j, p) + h <= D(j, c) + 2h for every j, so the
    cell's candidates are the segments within min_j D(j, c) + 2h of its centre.
    Those are found through the k-d tree of samples: a segment is within half
    the sample spacing of its nearest sample.
    """
    q = _stretch(queries)
    cell_of = np.floor(q / _CELL).astype(np.int64)
    low = cell_of.min(axis=0)
    span = cell_of.max(axis=0) - low + 1
    key = ((cell_of[:, 0] - low[0]) * span[1] + (cell_of[:, 1] - low[1])) * span[2] + (cell_of[:, 2] - low[2])
    keys, inverse = np.unique(key, return_inverse=True)
    cells = np.stack([keys // (span[1] * span[2]), (keys // span[2]) % span[1], keys % span[2]], axis=1) + low
    centre = (cells + 0.5) * _CELL
    h = _CELL * np.sqrt(3.0) / 2
    margin = 1e-3
    # Superset per cell: samples within (nearest sample + 2h + spacing/2) of the centre.
    ci, sample = tree_candidates(table.tree, centre,
                                 lambda nearest: nearest + 2 * h + table.spacing * 0.5 + margin)
    seg = table.sample_segment[sample]
    pair = np.unique(ci * np.int64(len(table.valid)) + seg)
    ci, seg = pair // len(table.valid), pair % len(table.valid)
    d = _segment_distance64(table, centre[ci], seg)
    best = np.full(len(cells), np.inf)
    np.minimum.at(best, ci, d)
    keep = d <= best[ci] + 2 * h + margin + 1e-5 * best[ci]
    ci, seg, d = ci[keep], seg[keep], d[keep]
    # Each query's distance to its cell's nearest segment bounds its own minimum:
    # a candidate k can only win if D(k, centre) - h <= that distance.
    first = np.searchsorted(ci, np.arange(len(cells)))
    cell_best = seg[first + _argmin_per_group(d, first)]
    bound = _segment_distance64(table, q, cell_best[inverse])
    # Expand each query to its cell's candidate list (ci is sorted by cell).
    count = np.bincount(ci, minlength=len(cells))
    per_query = count[inverse]
    qi = np.repeat(np.arange(len(q)), per_query)
    offset = np.arange(qi.size) - np.repeat(np.cumsum(per_query) - per_query, per_query)
    pos = first[inverse][qi] + offset
    near = d[pos] - h <= bound[qi] + margin + 1e-5 * bound[qi]
    return qi[near], seg[pos[near]]


def _argmin_per_group(values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Offset of the minimum within each contiguous group starting at `starts`."""
    lowest = np.minimum.reduceat(values, starts)
    sizes = np.diff(np.r_[starts, len(values)])
    hit = np.flatnonzero(values == np.repeat(lowest, sizes))
    group = np.searchsorted(starts, hit, side="right") - 1
    first_hit = np.r_[True, group[1:] != group[:-1]]
    return hit[first_hit] - starts[group[first_hit]]


def segment_side(query_xy, start, delta):
    """Sign of the cross product: +1 on the right (off-road) side of a segment.

    Args:
      query_xy: float32 `(..., 2)`; start, delta: float32 `(..., 3)` (or `(..., 2)`).
    Returns:
      float32 `(...)` in {-1, 0, 1}.
    """
    sx = query_xy[..., 0] - start[..., 0]
    sy = query_xy[..., 1] - start[..., 1]
    return array_namespace(query_xy, start).sign(_cross(sx, sy, delta[..., 0], delta[..., 1]))


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


def _side(table: SegmentTable, query_xy, seg):
    return segment_side(query_xy, table.start[seg], table.delta[seg])


def signed_distance_to_polylines(table: SegmentTable, queries: np.ndarray) -> np.ndarray:
    """Signed planar distance from points to the road-edge boundary.

    Args:
      table: the road edges, from `build_segment_table`.
      queries: float32 `(num_points, 3)`.
    Returns:
      float32 `(num_points,)`, negative on the road side.
    """
    queries = np.asarray(queries, _F)
    qi, si = _candidates(table, queries)
    d3 = _segment_distances(table, queries, qi, si)[1]
    # Nearest in 3D, ties to the lowest segment index (pairs are grouped by query).
    bq, best = first_minimum(qi, d3, si)
    bs = si[best]
    bt, _, d2 = _segment_distances(table, queries, bq, bs)
    xy = queries[bq, :2]
    n = _side(table, xy, bs)
    n_prior = _side(table, xy, table.prior[bs])
    n_next = _side(table, xy, table.next[bs])
    sign = corner_sign(bt, n, n_prior, n_next, table.convex_before[bs], table.convex_after[bs],
                       table.prior_valid[bs], table.next_valid[bs])
    out = np.empty(len(queries), _F)
    out[bq] = (sign * d2).astype(_F)
    return out


def distance_to_road_edge(corners_xyz: np.ndarray, valid: np.ndarray, table: SegmentTable) -> np.ndarray:
    """Signed distance of the most off-road corner of each box.

    Args:
      corners_xyz: float32 `(..., num_objects, num_steps, 4, 3)` bottom corners.
      valid: bool `(..., num_objects, num_steps)`.
    Returns:
      float32 `(..., num_objects, num_steps)`; -1e10 where invalid.
    """
    flat = corners_xyz.reshape(-1, 3)
    distance = signed_distance_to_polylines(table, flat).reshape(corners_xyz.shape[:-1])
    return np.where(valid, distance.max(axis=-1), -EXTREMELY_LARGE_DISTANCE)
