"""Candidate tables for the fixed-shape road-edge search on a device (`features.dense`).

A planar grid of `CELL_SIDE` (2 m) cells over a scene's road edges lists, per
cell, the `CELL_CANDIDATES` (64) segments nearest its centre, nearest first, and
two clearances: one that proves no other segment can be nearer, and one that
proves it of the segments after the first `CELL_NEAR_CANDIDATES` (24), so that a
query near a road edge needs only those; built once per scene on the host
(`backends.jax_backend`), gathered per box corner on the device.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from wosac_eval.features.compiled import cached_loop
from wosac_eval.features.road_edge.segments import (
    bucket_grid,
    gather_ring,
    gather_workspace,
    planar_squared,
    rings_around,
    search_buckets,
    segment_frames,
)
from wosac_eval.features.spatial import column_bounds

_F = np.float32


# Measured on the two real WOMD scenes' box corners (IDM rollouts): 4 m cells of 32 settled 64% of the
# queries (the rest searched every segment), 2 m cells of 64 settle 99.5-99.9%.
CELL_SIDE = 2.0  # metres: the planar grid of the candidate tables (a power of two: exact cell indices)
CELL_CANDIDATES = 64  # segments listed per cell
# The first segments of a cell's list with their own clearance: most queries need no more. Measured on
# the two real scenes' box corners (IDM rollouts), the first 16 settle 51-59% of the queries, 24 settle
# 82-83%, 32 settle 91%; the whole list 99.5-99.9%. 24 reads the fewest segments per query (24 + 18% of 64).
CELL_NEAR_CANDIDATES = 24
_CELL_BORDER = 10.0  # metres of grid around the segments' box
_GROUP_CELLS = 4  # cells along each side of a group that gathers its segments once
_MAX_CELLS = 1 << 20  # a larger grid (a map over 2 km across) gets a table that settles nothing (256 MiB at most)
_MARGIN = 1e-3  # metres of slack in the clearance, far above float32 rounding


def cell_candidate_table(
    start: np.ndarray,
    delta: np.ndarray,
    side: float = CELL_SIDE,
    k: int = CELL_CANDIDATES,
    near: int = CELL_NEAR_CANDIDATES,
) -> dict:
    """A planar grid over the segments: per cell, the `k` segments nearest its centre (nearest first),
    a clearance, and the clearance of its first `near` segments.

    The clearance is a lower bound of the planar distance from any point of the cell to every
    segment not listed. The selection distance of `segment_distances` is at least the planar
    distance, so a query whose nearest listed segment is nearer than the clearance has found the
    nearest of all, ties included (a tie outside would be nearer than the clearance). Queries
    outside the grid or beyond the clearance are for an exhaustive search; so are all of them for a
    map too large for a grid of at most `_MAX_CELLS` cells (`unsettling_cell_table`).

    Bounds (`_cell_table`): the listed segments are the `k` nearest the centre, found exactly among
    those its group of cells gathered, and the clearance is the next one's distance (or what the
    group left out can reach, if nearer) less the cell's half-diagonal and a slack far above
    float32 rounding. The list is sorted by distance from the centre (ties in the group's order), so
    every segment after the first `near` is at least as far as the `near + 1`-th: `near_clearance` is
    the clearance computed from that one's distance, a bound for the first `near` segments alone.

    Args:
      start, delta: float32 `(num_segments, 3)`, the segments the indices refer to (all valid).
    Returns:
      origin float32 `(2,)`, shape int32 `(2,)` (cells along x, y), candidates int32
      `(num_cells, num_candidates)` (cell `ix * shape[1] + iy`; nearest first; rows with fewer segments repeat
      their first), clearance and near_clearance float32 `(num_cells,)` (near_clearance <= clearance).
    """
    start, delta = np.ascontiguousarray(start, _F), np.ascontiguousarray(delta, _F)
    start64, delta64 = start[:, :2].astype(np.float64), delta[:, :2].astype(np.float64)
    low, high = column_bounds(np.concatenate([start64, start64 + delta64]))
    origin = np.floor(low - _CELL_BORDER)
    shape = np.ceil((high + _CELL_BORDER - origin) / side).astype(np.int64)
    if not np.isfinite(origin).all() or shape[0] * shape[1] > _MAX_CELLS:
        return unsettling_cell_table(k)  # every query searches all segments: exact, slower
    buckets = search_buckets(bucket_grid(start, delta, np.ones(len(start), bool)))
    cells = CellGrid(float(origin[0]), float(origin[1]), int(shape[0]), int(shape[1]), float(side))
    candidates, clearance, near_clearance = _cell_table(
        segment_frames(start, delta), cells, int(k), int(min(near, k)), buckets
    )
    return {
        "origin": origin.astype(_F),
        "shape": shape.astype(np.int32),
        "candidates": candidates,
        "clearance": clearance.astype(_F),
        "near_clearance": near_clearance.astype(_F),
    }


def unsettling_cell_table(k: int = CELL_CANDIDATES) -> dict:
    """A `cell_candidate_table` of one cell that settles no query (a clearance of -inf)."""
    return {
        "origin": np.zeros(2, _F),
        "shape": np.ones(2, np.int32),
        "candidates": np.zeros((1, k), np.int32),
        "clearance": np.full(1, -np.inf, _F),
        "near_clearance": np.full(1, -np.inf, _F),
    }


class CellGrid(NamedTuple):
    """The planar grid of a cell table: its lower corner, cells along x and y, and the cells' side (m)."""

    origin_x: float
    origin_y: float
    num_x: int
    num_y: int
    side: float


@cached_loop
def _cell_table(frame: Any, cells: Any, k: Any, near: Any, buckets: Any) -> Any:
    """`cell_candidate_table`'s lists and both clearances (float64), group of cells by group.

    A group of `_GROUP_CELLS` x `_GROUP_CELLS` cells gathers, ring by ring of buckets around its
    centre b, every segment within L = D(b) + 2h, where D(x) is the planar distance from x to
    its (k+1)-th nearest segment and h the group's half-diagonal; unseen segments are farther
    than L (the rings stop past it). A segment's distances from b and from a cell centre c differ
    by at most s = |c - b| <= h, so D(c) <= D(b) + s: the k+1 nearest of c are among the gathered
    segments within D(b) + 2s of b, and every other segment is at least D(c) from c, or beyond
    L - s if never gathered. A cell lists its k nearest in order of distance (a stable sort: ties in
    the group's order, the same k as any other rule that breaks ties so), so the first `near` are its
    `near` nearest and every other segment is at least the (near+1)-th nearest's distance away.
    """
    num_segments = frame.shape[0]
    origin_x, origin_y, num_x, num_y, side = cells
    grid = buckets.grid
    bucket_side = grid[2]
    candidates = np.empty((num_x * num_y, max(k, 1)), np.int32)
    clearance = np.empty(num_x * num_y, np.float64)
    near_clearance = np.empty(num_x * num_y, np.float64)
    gather = gather_workspace(num_segments, grid)
    gathered, gathered_distance = gather.segment, gather.key
    squared = np.empty(num_segments, np.float64)
    half_diagonal = side * math.sqrt(0.5)
    group_half = _GROUP_CELLS * half_diagonal
    tag = 0
    for gx in range(0, num_x, _GROUP_CELLS):
        for gy in range(0, num_y, _GROUP_CELLS):
            bx = origin_x + (gx + 0.5 * _GROUP_CELLS) * side
            by = origin_y + (gy + 0.5 * _GROUP_CELLS) * side
            # The segments around the group's centre by rings of buckets, until L is passed.
            _, _, first, last = rings_around(bx, by, grid)
            m, nearest_beyond = 0, np.inf  # D(b)
            for r in range(first, last + 1):
                if r > first and (r - 1) * bucket_side > nearest_beyond + 2.0 * group_half:
                    break  # every segment not met yet is at least (r - 1) * bucket_side away
                m = gather_ring(bx, by, r, frame, buckets, gather, tag, m)
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
                        squared[p] = planar_squared(px, py, group[p], frame)
                    # Nearest first; ties in the group's order (a stable sort).
                    nearest = np.argsort(squared[:kept], kind="mergesort")
                    listed = min(kept, k)
                    for p in range(listed):
                        candidates[row, p] = group[nearest[p]]
                    for p in range(listed, candidates.shape[1]):
                        candidates[row, p] = candidates[row, 0] if listed else 0
                    beyond = squared[nearest[k]] if kept > k else np.inf  # the squared D(c)
                    beyond_near = squared[nearest[near]] if kept > near else np.inf
                    never_gathered = nearest_beyond + 2.0 * group_half - shift
                    slack = _MARGIN + 1e-5 * max(abs(px), abs(py))
                    clearance[row] = min(math.sqrt(beyond), never_gathered) - half_diagonal - slack
                    near_clearance[row] = min(math.sqrt(beyond_near), never_gathered) - half_diagonal - slack
    return candidates, clearance, near_clearance
