"""The compiled pruned search for the nearest road-edge segment (numpy, numba loops).

The search needs one bound only: the selection distance of a segment (3D, heights
stretched) is at least the planar distance from the point to it, and that
changes by at most the distance the point moves. Around each query, segments
come from the table's 8 m buckets (`segments.BUCKET_SIDE`). A cell where
queries fall gets, on first use, every segment that can be nearest anywhere in
it, sorted by distance from its centre: cells are an eighth of a bucket's side
(1 m in 8 m buckets) where a segment is listed within two buckets, a whole
bucket farther out, and off the grid squares that grow with their distance from
the map (`_with_far_cells`). A query evaluates the exact float32 distance of its
first few candidates and stops at the first that cannot beat it. Boxes are
searched object by object, step by step, samples in a row, and each query first
tries the answer of the same corner of the box before: with the best distance
known at once, a candidate whose lower bound (float64, planar distance and
height gap, no division) is farther is not evaluated. A cell whose list does
not settle a query (a box on another level than every listed segment) grows
its list; anything left searches the buckets ring by ring around itself.
Results equal an all-pairs search bit for bit (tests compare with brute force). The signed
distances of the found segments, for points and boxes, are in `signed_distance`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from wosac_eval.features.compiled import cached_loop, compiled
from wosac_eval.features.road_edge.segments import (
    Z_STRETCH,
    SegmentTable,
    bucket_coordinate,
    bucket_of,
    gather_ring,
    planar_distance,
    planar_squared,
    ring_buckets,
    ring_buffer,
    rings_around,
    search_grid,
    segment_distances,
)
from wosac_eval.features.spatial import non_finite_pick

_F = np.float32
_CELLS_PER_BUCKET = 8  # along each axis, near the road edges: cells of an 8th of the bucket side (1 m)
_LIST_SLACK = 3.0  # metres listed beyond a cell's nearest planar distance: heights up to 1 m apart
# Fewer queries per cell than this, and each query's own ring search costs less than its cell's list
# (about 4 us a list against 0.5-0.9 us a ring search on a WOMD map): scattered points, such as the
# analysis's moving vehicles every half second, 1.5-4.5 per cell; scoring's box corners are 50-150.
SPARSE_QUERIES_PER_CELL = 6.0
_NOT_FOUND = _OFF_GRID = -1
_NON_FINITE = -2


_segment_distances = compiled(segment_distances)


@numba.njit
def _distance_bound(qx, qy, qz, k, frame):
    """A lower bound of the squared selection distance from a point to segment k (float64, no division):
    the squared planar distance to the segment plus the stretched squared height gap to its z range
    (every point of the segment is at least that far in each)."""
    below = max(frame[k, 5] - qz, qz - frame[k, 6], 0.0) * Z_STRETCH
    return planar_squared(qx, qy, k, frame) + below * below


@numba.njit
def _rounding_margin(distance, length):
    """How far below the true distance the float32 selection distance can fall (generously)."""
    return 1e-3 + 1e-5 * (distance + 2.0 * length)


@numba.njit
def _selection(px, py, pz, k, start, delta):
    return _segment_distances(px, py, pz, start[k, 0], start[k, 1], start[k, 2], delta[k, 0], delta[k, 1], delta[k, 2])[
        1
    ]


@cached_loop
def _ring_search(px, py, pz, start, delta, grid, bucket_start, bucket_segments, seen, tag, ring, max_length):
    """The nearest segment of one point by expanding rings of buckets around it (exact, any point).

    Before ring r, every segment not met yet crosses only buckets r or more buckets away,
    so it is at least (r - 1) * side away in the plane: the search stops there.
    """
    if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
        return _NON_FINITE, 0
    side = grid[2]
    bi, bj, first, last = rings_around(np.float64(px), np.float64(py), grid)
    best, best_k, evaluated = np.float32(np.inf), _NOT_FOUND, 0
    for r in range(first, last + 1):
        if r > first and (r - 1) * side > best + _rounding_margin(best, max_length):
            break
        for q in range(ring_buckets(bi, bj, r, grid, ring)):
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
def _cell_candidates(
    cx,
    cy,
    half_diagonal,
    min_reach,
    frame,
    length,
    grid,
    bucket_start,
    bucket_segments,
    seen,
    tag,
    ring,
    out_segment,
    out_key,
):
    """Every segment that can be nearest somewhere in a cell, by key; returns (count, clearance).

    For a point q within r of the centre c, segment k's planar distance is at least
    P_k(c) - r: segments with P_k(c) - h above R = min_k P_k(c) + h + slack are left out, and a
    query settles when what it found is nearer than what they can reach. The key of a listed
    segment is P_k(c) less its rounding margin; lists are sorted by key.
    """
    side = grid[2]
    bi, bj, first, last = rings_around(cx, cy, grid)
    reach = np.inf  # R
    n = 0
    for r in range(first, last + 1):
        if r > first and (r - 1) * side - half_diagonal > reach:
            break
        gathered = gather_ring(
            cx, cy, bi, bj, r, frame, grid, bucket_start, bucket_segments, seen, tag, ring, out_segment, out_key, n
        )
        for p in range(n, gathered):
            reach = min(reach, max(out_key[p] + half_diagonal + _LIST_SLACK, min_reach))
        n = gathered
    return _listed(n, reach, half_diagonal, length, out_segment, out_key), reach


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
        d = planar_distance(cx, cy, k, frame)
        reach = min(reach, d + half_diagonal + _LIST_SLACK)
        out_segment[n] = k
        out_key[n] = d
        n += 1
    return _listed(n, reach, half_diagonal, length, out_segment, out_key), reach


@cached_loop
def _query_cells(queries, grid, bucket_start):
    """The cell of each query, numbered as first met, and each cell's centre and half-diagonal.

    Cells are an 8th of the bucket side (`_CELLS_PER_BUCKET`: 1 m in 8 m buckets) where the 5 x 5
    buckets around hold a segment; farther out one list serves a whole bucket (cells of 1 m there
    would each list a wide ring of segments).

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
        fx, fy = bucket_coordinate(px, origin_x, side), bucket_coordinate(py, origin_y, side)
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
    ring = ring_buffer(grid)
    origin_x, origin_y, side = grid[0], grid[1], grid[2]
    # Cells smaller than a bucket take their segments among those of their bucket, built once.
    parent = np.empty(num_cells, np.int64)
    for c in range(num_cells):
        inside = half_diagonal[c] < side * math.sqrt(0.5) and min_reach[c] == 0
        parent[c] = (
            bucket_of(centre[c, 0], origin_x, side) * grid[4] + bucket_of(centre[c, 1], origin_y, side)
            if inside
            else -1
        )
    order = np.argsort(parent)
    bucket_list, bucket_key = np.empty(num_segments, np.int32), np.empty(num_segments, np.float64)
    bucket_count, current, used = 0, -2, 0
    bucket_x = bucket_y = 0.0
    for c in order:
        if parent[c] >= 0 and parent[c] != current:
            current = parent[c]
            bi, bj = current // grid[4], current % grid[4]
            bucket_x, bucket_y = origin_x + (bi + 0.5) * side, origin_y + (bj + 0.5) * side
            bucket_count, _ = _cell_candidates(
                bucket_x,
                bucket_y,
                side * math.sqrt(0.5),
                0.0,
                frame,
                length,
                grid,
                bucket_start,
                bucket_segments,
                seen,
                num_cells + c,
                ring,
                bucket_list,
                bucket_key,
            )
        if parent[c] >= 0:
            shift = math.hypot(centre[c, 0] - bucket_x, centre[c, 1] - bucket_y)
            m, reach[c] = _cell_candidates_among(
                centre[c, 0],
                centre[c, 1],
                half_diagonal[c],
                frame,
                length,
                bucket_list,
                bucket_key,
                bucket_count,
                shift,
                scratch_segment,
                scratch_key,
            )
        else:
            m, reach[c] = _cell_candidates(
                centre[c, 0],
                centre[c, 1],
                half_diagonal[c],
                min_reach[c],
                frame,
                length,
                grid,
                bucket_start,
                bucket_segments,
                seen,
                c,
                ring,
                scratch_segment,
                scratch_key,
            )
        while used + m > segment.shape[0]:
            segment, key = _grown(segment), _grown(key)
        segment[used : used + m] = scratch_segment[:m]
        key[used : used + m] = scratch_key[:m]
        begin[c], end[c] = used, used + m
        used += m
    return begin, end, segment[:used], key[:used], reach


@cached_loop
def _search_lists(
    queries, cell, centre, half_diagonal, begin, end, segment, key, reach, max_length, start, delta, frame, hint_stride
):
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
    ring = ring_buffer(grid)
    evaluated = 0
    for i in range(queries.shape[0]):
        if found[i] == _NOT_FOUND:
            found[i], count = _ring_search(
                queries[i, 0],
                queries[i, 1],
                queries[i, 2],
                start,
                delta,
                grid,
                bucket_start,
                bucket_segments,
                seen,
                i,
                ring,
                max_length,
            )
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
      counts: a dict that gets the work done: "cells" (candidate lists built; none where the queries
        are scattered, fewer than `SPARSE_QUERIES_PER_CELL` per cell: each then searches the rings of
        buckets around it), "pairs evaluated" (selection distances computed).
      hint_stride: each query starts from the answer of the query this many before it (a hint only:
        the result does not depend on it; it saves work where that query is near).
    Returns:
      int64 `(n,)`: a segment, `_NOT_FOUND` when no segment is listed, `_NON_FINITE` for a point
      with a NaN or infinite coordinate.
    """
    grid = search_grid(table.bucket_origin, table.bucket_side, table.bucket_shape, table.segment_buckets)
    cell, centre, half_diagonal = _query_cells(queries, grid, table.bucket_start)
    cell, centre, half_diagonal = _with_far_cells(queries, cell, centre, half_diagonal, table)
    max_length = float(table.length[table.bucket_segments].max(initial=0.0))
    work = {"cells": 0, "pairs evaluated": 0}

    def search(rows, cells, min_reach):
        lists = _cell_lists(
            centre[cells],
            half_diagonal[cells],
            min_reach,
            table.frame,
            table.length,
            grid,
            table.bucket_start,
            table.bucket_segments,
        )
        number = np.full(len(centre) + 2, -1, np.int64)
        number[cells] = np.arange(len(cells))
        number[_NON_FINITE] = _NON_FINITE  # the codes of queries without a cell stay
        found, needed, evaluated = _search_lists(
            queries[rows],
            number[cell[rows]],
            centre[cells],
            half_diagonal[cells],
            *lists,
            max_length,
            table.start,
            table.delta,
            table.frame,
            hint_stride,
        )
        work["cells"] += len(cells)
        work["pairs evaluated"] += evaluated
        return found, needed

    if queries.shape[0] < SPARSE_QUERIES_PER_CELL * len(centre):
        found = np.full(queries.shape[0], _NOT_FOUND, np.int64)  # scattered: every query searches the buckets
    else:
        found, needed = search(slice(None), np.arange(len(centre)), np.zeros(len(centre)))
        # Cells whose list left queries unsettled (a box on another level than the road edges near it):
        # their lists grown to settle them, once per cell; whatever is left searches the buckets.
        grow = np.flatnonzero(needed > 0)
        if grow.size:
            again = np.flatnonzero((found == _NOT_FOUND) & np.isin(cell, grow))
            found[again] = search(again, grow, needed[grow])[0]
    if (found == _NOT_FOUND).any():
        work["pairs evaluated"] += _ring_searches(
            queries, found, table.start, table.delta, grid, table.bucket_start, table.bucket_segments, max_length
        )
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
    out[: a.shape[0]] = a
    return out


def nearest_segments(
    table: SegmentTable, queries: np.ndarray, counts: dict | None = None, hint_stride: int = 1
) -> np.ndarray:
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
