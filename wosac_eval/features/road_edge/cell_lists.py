"""The candidate lists of the pruned road-edge search (`pruned_search`): cells where queries fall, and
for each cell every segment that can be nearest anywhere in it, sorted by distance from its centre.

Cells are an eighth of a bucket's side (1 m in 8 m buckets) where a segment is listed within two
buckets, a whole bucket farther out, and off the grid squares that grow with their distance from the
map (`with_far_cells`). A cell's list comes with its clearance (its reach R): a query nearer to what
it found than R settles in the list; cells smaller than a bucket take their lists among their
bucket's, built once.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numba
import numpy as np

from wosac_eval.features.compiled import cached_loop
from wosac_eval.features.road_edge.segments import (
    Gather,
    SegmentTable,
    bucket_coordinate,
    bucket_of,
    gather_ring,
    gather_workspace,
    planar_distance,
    rings_around,
)

_CELLS_PER_BUCKET = 8  # along each axis, near the road edges: cells of an 8th of the bucket side (1 m)
_LIST_SLACK = 3.0  # metres listed beyond a cell's nearest planar distance: heights up to 1 m apart
# A query's cell, or what it has instead (`query_cells`); NOT_FOUND: a search that listed nothing for it.
NOT_FOUND = OFF_GRID = -1
NON_FINITE = -2


class CellLists(NamedTuple):
    """The candidate lists of the cells where queries fall, as the search reads them.

    Attributes:
      centre: float64 `(num_cells, 2)`; half_diagonal: float64 `(num_cells,)`.
      begin, end: int64 `(num_cells,)`, where each cell's list lies in `segment` (int32) and `key`
        (float64, sorted within a list); reach: float64 `(num_cells,)`, each cell's R (`cell_lists`).
    """

    centre: np.ndarray
    half_diagonal: np.ndarray
    begin: np.ndarray
    end: np.ndarray
    segment: np.ndarray
    key: np.ndarray
    reach: Any


@numba.njit
def rounding_margin(distance: Any, length: Any) -> Any:
    """How far below the true distance the float32 selection distance can fall (generously)."""
    return 1e-3 + 1e-5 * (distance + 2.0 * length)


@numba.njit(error_model="numpy")
def _cell_candidates(
    cx: Any,
    cy: Any,
    half_diagonal: Any,
    min_reach: Any,
    segments: Any,
    buckets: Any,
    gather: Any,
    tag: Any,
) -> Any:
    """Every segment that can be nearest somewhere in a cell, by key, into `gather.segment` and
    `gather.key`; returns (count, clearance).

    For a point q within r of the centre c, segment k's planar distance is at least
    P_k(c) - r: segments with P_k(c) - h above R = min_k P_k(c) + h + slack are left out, and a
    query settles when what it found is nearer than what they can reach. The key of a listed
    segment is P_k(c) less its rounding margin; lists are sorted by key.
    """
    side = buckets.grid[2]
    _, _, first, last = rings_around(cx, cy, buckets.grid)
    reach = np.inf  # R
    n = 0
    for r in range(first, last + 1):
        if r > first and (r - 1) * side - half_diagonal > reach:
            break
        gathered = gather_ring(cx, cy, r, segments.frame, buckets, gather, tag, n)
        for p in range(n, gathered):
            reach = min(reach, max(gather.key[p] + half_diagonal + _LIST_SLACK, min_reach))
        n = gathered
    return _listed(n, reach, half_diagonal, segments.length, gather.segment, gather.key), reach


@numba.njit
def _listed(n: Any, reach: Any, half_diagonal: Any, length: Any, out_segment: Any, out_key: Any) -> Any:
    """Keeps the gathered segments (first n of `out_segment`, their centre distances in `out_key`)
    that can be nearest in the cell, keyed and sorted; returns their count.

    An insertion sort: segments come gathered near to far from a point near the cell (the
    cell's parent bucket's order), so each moves a few places at most.
    """
    m = 0
    for p in range(n):
        if out_key[p] - half_diagonal <= reach:
            k = out_segment[p]
            value = out_key[p] * (1 - 1e-5) - rounding_margin(0.0, length[k])
            q = m
            while q > 0 and out_key[q - 1] > value:
                out_segment[q], out_key[q] = out_segment[q - 1], out_key[q - 1]
                q -= 1
            out_segment[q], out_key[q] = k, value
            m += 1
    return m


@numba.njit
def _cell_candidates_among(
    cx: Any,
    cy: Any,
    half_diagonal: Any,
    segments: Any,
    among: Any,
    count: int,
    shift: Any,
    gather: Any,
) -> Any:
    """`_cell_candidates` of a cell inside a square whose list `among.segment[:count]` holds every
    segment that can be nearest in it (a cell's list is a subset of that of a square around it: its
    bounds are tighter), into `gather.segment` and `gather.key`; returns (count, clearance).

    `among.key` are the square's keys (sorted, each at most the segment's distance from the square's
    centre), `shift` the distance between the two centres: a segment's distance from the cell's centre
    is at least its key less `shift`, so the scan stops at the first whose key shows it can be
    neither listed nor nearer than the reach so far (nor can any after it).
    """
    reach = np.inf
    n = 0
    for p in range(count):
        if among.key[p] - shift - half_diagonal > reach:
            break
        k = among.segment[p]
        d = planar_distance(cx, cy, k, segments.frame)
        reach = min(reach, d + half_diagonal + _LIST_SLACK)
        gather.segment[n] = k
        gather.key[n] = d
        n += 1
    return _listed(n, reach, half_diagonal, segments.length, gather.segment, gather.key), reach


@cached_loop
def query_cells(queries: Any, buckets: Any) -> Any:
    """The cell of each query, numbered as first met, and each cell's centre and half-diagonal.

    Cells are an 8th of the bucket side (`_CELLS_PER_BUCKET`: 1 m in 8 m buckets) where the 5 x 5
    buckets around hold a segment; farther out one list serves a whole bucket (cells of 1 m there
    would each list a wide ring of segments).

    Returns:
      (cell int64 `(num_points,)`: `OFF_GRID` for a point off the grid, `NON_FINITE` for one with a NaN
      or infinite coordinate; centre float64 `(num_cells, 2)`; half-diagonal float64 `(num_cells,)`).
    """
    origin_x, origin_y, side, num_x, num_y, x0, x1, y0, y1 = buckets.grid
    n = queries.shape[0]
    cell = np.empty(n, np.int64)  # the bucket first, then the cell
    within = np.empty((n, 2), np.float64)  # where in its bucket a query lies, in [0, 1)
    block_of_bucket = np.full(num_x * num_y, -1, np.int64)
    num_blocks = 0
    for i in range(n):
        px, py = np.float64(queries[i, 0]), np.float64(queries[i, 1])
        if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(queries[i, 2])):
            cell[i] = NON_FINITE
            continue
        # Its place in its bucket is kept for the second pass (computed twice, it cost as much again).
        fx, fy = bucket_coordinate(px, origin_x, side), bucket_coordinate(py, origin_y, side)
        bi, bj = math.floor(fx), math.floor(fy)
        if not (0 <= bi < num_x and 0 <= bj < num_y):
            cell[i] = OFF_GRID
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
            near = _segments_around(b // num_y, b % num_y, 2, buckets)
            division[block_of_bucket[b]] = _CELLS_PER_BUCKET if near else 1
    cell_id = np.full((num_blocks, _CELLS_PER_BUCKET * _CELLS_PER_BUCKET), -1, np.int64)
    centre = np.empty((min(n, num_blocks * _CELLS_PER_BUCKET * _CELLS_PER_BUCKET), 2), np.float64)
    half_diagonal = np.empty(centre.shape[0], np.float64)
    num_cells = 0
    for i in range(n):
        b = cell[i]
        if b < 0:  # OFF_GRID and NON_FINITE stay
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


@numba.njit
def _segments_around(bi: Any, bj: Any, r: Any, buckets: Any) -> bool:
    """Whether a bucket within `r` buckets of (bi, bj) lists a segment."""
    origin_x, origin_y, side, num_x, num_y, x0, x1, y0, y1 = buckets.grid
    bucket_start = buckets.start
    for i in range(max(bi - r, 0), min(bi + r, num_x - 1) + 1):
        for j in range(max(bj - r, 0), min(bj + r, num_y - 1) + 1):
            if bucket_start[i * num_y + j + 1] > bucket_start[i * num_y + j]:
                return True
    return False


@numba.njit
def _parent_buckets(centre: Any, half_diagonal: Any, min_reach: Any, grid: Any) -> Any:
    """The bucket of each cell smaller than a bucket, which takes its segments among those of its bucket
    (listed once for all its cells), else -1: int64 `(num_cells,)`."""
    origin_x, origin_y, side = grid[0], grid[1], grid[2]
    parent = np.empty(centre.shape[0], np.int64)
    for c in range(centre.shape[0]):
        inside = half_diagonal[c] < side * math.sqrt(0.5) and min_reach[c] == 0
        parent[c] = (
            bucket_of(centre[c, 0], origin_x, side) * grid[4] + bucket_of(centre[c, 1], origin_y, side)
            if inside
            else -1
        )
    return parent


@cached_loop
def cell_lists(centre: Any, half_diagonal: Any, min_reach: Any, segments: Any, buckets: Any) -> Any:
    """The candidate list of each cell (`_cell_candidates`), one after the other.

    Args:
      centre: float64 `(num_cells, 2)`; half_diagonal, min_reach: float64 `(num_cells,)`.
      segments: the table's `SearchedSegments`; buckets: its `Buckets`.
    Returns:
      (begin, end int64 `(num_cells,)`: where each cell's list lies in segment int32 and key
      float64 `(list entries,)`; reach float64 `(num_cells,)`: the R of each cell).
    """
    num_cells, num_segments = centre.shape[0], segments.frame.shape[0]
    begin, end = np.zeros(num_cells, np.int64), np.zeros(num_cells, np.int64)
    reach = np.empty(num_cells, np.float64)
    segment = np.empty(max(16, 32 * num_cells), np.int32)
    key = np.empty(segment.shape[0], np.float64)
    # The cells' gathers and their buckets' share which segments were seen (under tags of their own).
    cell = gather_workspace(num_segments, buckets.grid)
    bucket = Gather(cell.seen, cell.ring, np.empty(num_segments, np.int32), np.empty(num_segments, np.float64))
    origin_x, origin_y, side, num_y = buckets.grid[0], buckets.grid[1], buckets.grid[2], buckets.grid[4]
    parent = _parent_buckets(centre, half_diagonal, min_reach, buckets.grid)
    bucket_count, current, used = 0, -2, 0
    bucket_x = bucket_y = 0.0
    for c in np.argsort(parent):
        if parent[c] >= 0 and parent[c] != current:
            current = parent[c]
            bucket_x, bucket_y = origin_x + (current // num_y + 0.5) * side, origin_y + (current % num_y + 0.5) * side
            bucket_count, _ = _cell_candidates(
                bucket_x, bucket_y, side * math.sqrt(0.5), 0.0, segments, buckets, bucket, num_cells + c
            )
        if parent[c] >= 0:
            shift = math.hypot(centre[c, 0] - bucket_x, centre[c, 1] - bucket_y)
            m, reach[c] = _cell_candidates_among(
                centre[c, 0], centre[c, 1], half_diagonal[c], segments, bucket, bucket_count, shift, cell
            )
        else:
            m, reach[c] = _cell_candidates(
                centre[c, 0], centre[c, 1], half_diagonal[c], min_reach[c], segments, buckets, cell, c
            )
        while used + m > segment.shape[0]:
            segment, key = _grown(segment), _grown(key)
        segment[used : used + m] = cell.segment[:m]
        key[used : used + m] = cell.key[:m]
        begin[c], end[c] = used, used + m
        used += m
    return begin, end, segment[:used], key[:used], reach


@numba.njit
def _grown(a: Any) -> Any:
    """`a` in an array twice as long (first axis), its rows kept."""
    out = np.empty((2 * a.shape[0],) + a.shape[1:], a.dtype)
    out[: a.shape[0]] = a
    return out


_FAR_CELL_RATIO = 1024.0  # a cell off the grid is about this many times smaller than its distance to the map


def with_far_cells(
    queries: np.ndarray, cell: np.ndarray, centre: np.ndarray, half_diagonal: np.ndarray, table: SegmentTable
) -> Any:
    """`query_cells` with cells for the finite points off the grid (placeholder states, a rollout
    gone kilometres away): squares of a power-of-two side, about 1/1024 of their distance to
    the map and at least a bucket, so one list serves the points near one another."""
    far = np.flatnonzero(cell == OFF_GRID)
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
