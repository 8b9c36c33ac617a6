"""The compiled pruned search for the nearest road-edge segment (numpy, numba loops).

The search needs one bound only: the selection distance of a segment (3D, heights
stretched) is at least the planar distance from the point to it, and that
changes by at most the distance the point moves. Around each query, segments
come from the table's 8 m buckets (`segments.BUCKET_SIDE`). A cell where
queries fall gets, on first use, every segment that can be nearest anywhere in
it, sorted by distance from its centre: cells are an eighth of a bucket's side
(1 m in 8 m buckets) where a segment is listed within two buckets, a whole
bucket farther out, and off the grid squares that grow with their distance from
the map (`with_far_cells`). A query evaluates the exact float32 distance of its
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
from typing import Any

import numba
import numpy as np

from wosac_eval.features.compiled import cached_loop, compiled
from wosac_eval.features.road_edge.cell_lists import (
    NON_FINITE,
    NOT_FOUND,
    CellLists,
    cell_lists,
    query_cells,
    rounding_margin,
    with_far_cells,
)
from wosac_eval.features.road_edge.segments import (
    Z_STRETCH,
    Gather,
    SegmentTable,
    planar_squared,
    ring_buckets,
    ring_buffer,
    rings_around,
    segment_distances,
)
from wosac_eval.features.spatial import non_finite_pick

_F = np.float32
# Fewer queries per cell than this, and each query's own ring search costs less than its cell's list
# (about 4 us a list against 0.5-0.9 us a ring search on a WOMD map): scattered points, such as the
# analysis's moving vehicles every half second, 1.5-4.5 per cell; scoring's box corners are 50-150.
SPARSE_QUERIES_PER_CELL = 6.0


_segment_distances = compiled(segment_distances)


@numba.njit
def _distance_bound(qx: Any, qy: Any, qz: Any, k: int, frame: Any) -> Any:
    """A lower bound of the squared selection distance from a point to segment k (float64, no division):
    the squared planar distance to the segment plus the stretched squared height gap to its z range
    (every point of the segment is at least that far in each)."""
    below = max(frame[k, 5] - qz, qz - frame[k, 6], 0.0) * Z_STRETCH
    return planar_squared(qx, qy, k, frame) + below * below


@numba.njit
def _selection(px: Any, py: Any, pz: Any, k: int, start: Any, delta: Any) -> Any:
    return _segment_distances(px, py, pz, start[k, 0], start[k, 1], start[k, 2], delta[k, 0], delta[k, 1], delta[k, 2])[
        1
    ]


@cached_loop
def _ring_search(
    px: float, py: float, pz: float, segments: Any, buckets: Any, gather: Any, tag: Any, max_length: Any
) -> Any:
    """The nearest segment of one point by expanding rings of buckets around it (exact, any point);
    `gather.seen` marks the segments met (under `tag`), `gather.ring` holds a ring's buckets.

    Before ring r, every segment not met yet crosses only buckets r or more buckets away,
    so it is at least (r - 1) * side away in the plane: the search stops there.
    """
    if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
        return NON_FINITE, 0
    grid, ring, seen = buckets.grid, gather.ring, gather.seen
    side = grid[2]
    bi, bj, first, last = rings_around(np.float64(px), np.float64(py), grid)
    best, best_k, evaluated = np.float32(np.inf), NOT_FOUND, 0
    for r in range(first, last + 1):
        if r > first and (r - 1) * side > best + rounding_margin(best, max_length):
            break
        for q in range(ring_buckets(bi, bj, r, grid, ring)):
            for p in range(buckets.start[ring[q]], buckets.start[ring[q] + 1]):
                k = buckets.segments[p]
                if seen[k] == tag:
                    continue
                seen[k] = tag
                d = _selection(px, py, pz, k, segments.start, segments.delta)
                evaluated += 1
                if d < best or (d == best and k < best_k):
                    best, best_k = d, k
    return best_k, evaluated


@cached_loop
def _search_lists(queries: Any, cell: Any, lists: Any, segments: Any, max_length: Any, hint_stride: Any) -> Any:
    """The nearest segment of each query among its cell's list (`lists`: `cell_lists.CellLists`).

    The nearest segment of the query `hint_stride` before (the same corner of a nearby box, in
    the order `box_distance_to_road_edge` gives) is evaluated first: usually the answer, so that
    few others pass the bounds. Then candidates are taken in key order until the next one's key
    shows that nothing further on can be nearer; a candidate that `_distance_bound` puts farther
    than the best so far is not evaluated. (Any valid segment may be evaluated: the result is
    the nearest of those evaluated, and the bounds cover every segment that could beat it.)

    Returns:
      (int64 `(num_points,)`: the segment, `NOT_FOUND` where the list does not settle it (or the query
      has no cell), `NON_FINITE` for a NaN or infinite point; float64 `(num_cells,)`: the R a
      cell's list needs to settle all its queries, 0 where it does; the number of distances
      evaluated).
    """
    centre, half_diagonal, begin, end, segment, key, reach = lists
    start, delta, frame = segments.start, segments.delta, segments.frame
    out = np.empty(queries.shape[0], np.int64)
    needed = np.zeros(centre.shape[0], np.float64)
    evaluated = 0
    margin = rounding_margin(0.0, max_length)
    for i in range(queries.shape[0]):
        px, py, pz = queries[i, 0], queries[i, 1], queries[i, 2]
        c = cell[i]
        if c < 0:  # off the grid (not found here) or not finite
            out[i] = c
            continue
        qx, qy, qz = np.float64(px), np.float64(py), np.float64(pz)
        ox, oy = qx - centre[c, 0], qy - centre[c, 1]
        off_centre = math.sqrt(ox * ox + oy * oy)
        best, best_k, reject = np.float32(np.inf), NOT_FOUND, np.inf
        hint = out[i - hint_stride] if i >= hint_stride else NOT_FOUND
        if hint >= 0:
            evaluated += 1
            best = _selection(px, py, pz, hint, start, delta)
            best_k = hint
            bound = np.float64(best) + rounding_margin(np.float64(best), max_length)
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
                bound = np.float64(best) + rounding_margin(np.float64(best), max_length)
                reject = bound * bound
        # A segment left out is farther in the plane than this, less its rounding.
        unlisted = (reach[c] + half_diagonal[c] - off_centre) * (1 - 1e-5) - margin
        if best < unlisted:
            out[i] = best_k
        else:
            out[i] = NOT_FOUND
            if best_k >= 0:  # R that would settle it (on another level than the listed segments)
                needed[c] = max(needed[c], (best + margin) / (1 - 1e-5) + off_centre - half_diagonal[c] + 1e-3)
    return out, needed, evaluated


@cached_loop
def _ring_searches(queries: Any, found: Any, segments: Any, buckets: Any, max_length: Any) -> Any:
    """`_ring_search` for every query `found` left `NOT_FOUND` (in place); returns the distances evaluated."""
    none = np.empty(0, np.int32), np.empty(0, np.float64)  # the ring search keeps no gathered list
    gather = Gather(np.full(segments.start.shape[0], -1, np.int64), ring_buffer(buckets.grid), *none)
    evaluated = 0
    for i in range(queries.shape[0]):
        if found[i] == NOT_FOUND:
            found[i], count = _ring_search(
                queries[i, 0], queries[i, 1], queries[i, 2], segments, buckets, gather, i, max_length
            )
            evaluated += count
    return evaluated


def _nearest_segments(
    queries: np.ndarray, table: SegmentTable, counts: dict | None = None, hint_stride: int = 1
) -> np.ndarray:
    """The nearest valid segment of each point (stretched selection distance, lowest index on ties).

    Args:
      queries: float32 `(num_points, 3)`, contiguous.
      counts: a dict that gets the work done: "cells" (candidate lists built; none where the queries
        are scattered, fewer than `SPARSE_QUERIES_PER_CELL` per cell: each then searches the rings of
        buckets around it), "pairs evaluated" (selection distances computed).
      hint_stride: each query starts from the answer of the query this many before it (a hint only:
        the result does not depend on it; it saves work where that query is near).
    Returns:
      int64 `(num_points,)`: a segment, `NOT_FOUND` when no segment is listed, `NON_FINITE` for a point
      with a NaN or infinite coordinate.
    """
    buckets, segments = table.buckets(), table.searched()
    cell, centre, half_diagonal = query_cells(queries, buckets)
    cell, centre, half_diagonal = with_far_cells(queries, cell, centre, half_diagonal, table)
    max_length = float(table.length[table.bucket_segments].max(initial=0.0))
    work = {"cells": 0, "pairs evaluated": 0}

    def search(rows: np.ndarray | slice, cells: np.ndarray, min_reach: Any) -> Any:
        lists = CellLists(
            centre[cells],
            half_diagonal[cells],
            *cell_lists(centre[cells], half_diagonal[cells], min_reach, segments, buckets),
        )
        number = np.full(len(centre) + 2, -1, np.int64)
        number[cells] = np.arange(len(cells))
        number[NON_FINITE] = NON_FINITE  # the codes of queries without a cell stay
        found, needed, evaluated = _search_lists(
            queries[rows], number[cell[rows]], lists, segments, max_length, hint_stride
        )
        work["cells"] += len(cells)
        work["pairs evaluated"] += evaluated
        return found, needed

    if queries.shape[0] < SPARSE_QUERIES_PER_CELL * len(centre):
        found = np.full(queries.shape[0], NOT_FOUND, np.int64)  # scattered: every query searches the buckets
    else:
        found, needed = search(slice(None), np.arange(len(centre)), np.zeros(len(centre)))
        # Cells whose list left queries unsettled (a box on another level than the road edges near it):
        # their lists grown to settle them, once per cell; whatever is left searches the buckets.
        grow = np.flatnonzero(needed > 0)
        if grow.size:
            again = np.flatnonzero((found == NOT_FOUND) & np.isin(cell, grow))
            found[again] = search(again, grow, needed[grow])[0]
    if (found == NOT_FOUND).any():
        work["pairs evaluated"] += _ring_searches(queries, found, segments, buckets, max_length)
    if counts is not None:
        counts.update(work)
    return found


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
