"""Signed distance to the road edge of points and of box corners, from the nearest segments that
`pruned_search` finds (numpy, numba loops): the official sign rule (`segments.corner_sign`) applied to
the nearest segment and its neighbours, and the most off-road corner of each box.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.features.box_geometry import box_corners
from wosac_eval.features.compiled import cached_loop, compiled
from wosac_eval.features.road_edge.pruned_search import nearest_segments
from wosac_eval.features.road_edge.segments import (
    EXTREMELY_LARGE_DISTANCE,
    SegmentTable,
    corner_sign,
    segment_distances,
    side_of_segment,
)

_F = np.float32
_segment_distances = compiled(segment_distances)
_side_of = compiled(side_of_segment)
_corner_sign = compiled(corner_sign)


@cached_loop
def _signed_distances(queries: Any, segment: Any, sides: Any, group: Any) -> Any:
    """Signed planar distance of each point to its nearest segment (`segment`, `(num_points,)`; `sides`: the
    table's `SegmentSides`): the largest of each `group` of consecutive points (numpy's maximum: NaN
    passes on), float32 `(n // group,)`."""
    start, delta, valid, prior, next_, prior_valid, next_valid, convex_before, convex_after = sides
    out = np.empty(queries.shape[0] // group, np.float32)
    for i in range(queries.shape[0]):
        px, py, pz, k = queries[i, 0], queries[i, 1], queries[i, 2], segment[i]
        rel_t, _, planar = _segment_distances(
            px, py, pz, start[k, 0], start[k, 1], start[k, 2], delta[k, 0], delta[k, 1], delta[k, 2]
        )
        a, b = prior[k], next_[k]
        side = _side_of(px, py, start[k, 0], start[k, 1], delta[k, 0], delta[k, 1])
        # The neighbours' sides count only past the segment's ends (`corner_sign`).
        side_prior = _side_of(px, py, start[a, 0], start[a, 1], delta[a, 0], delta[a, 1]) if rel_t < 0 else side
        side_next = _side_of(px, py, start[b, 0], start[b, 1], delta[b, 0], delta[b, 1]) if rel_t > 1 else side
        sign = _corner_sign(
            rel_t, side, side_prior, side_next, convex_before[k], convex_after[k], prior_valid[k], next_valid[k]
        )
        # A padding segment's distance is 1e10, as officially (only non-finite points get one).
        distance = sign * (planar if valid[k] else EXTREMELY_LARGE_DISTANCE)
        g = i // group
        out[g] = distance if i % group == 0 or not ((out[g] > distance) | (out[g] != out[g])) else out[g]
    return out


def signed_distance_to_polylines(table: SegmentTable, queries: np.ndarray) -> np.ndarray:
    """Signed planar distance from points to the road-edge boundary.

    Args:
      table: the road edges, from `build_segment_table`.
      queries: float32 `(num_points, 3)`.
    Returns:
      float32 `(num_points,)`, negative on the road side.
    """
    return _signed_distance_groups(table, np.ascontiguousarray(queries, _F).reshape(-1, 3), 1)


def _signed_distance_groups(table: SegmentTable, queries: np.ndarray, group: int, counts: dict | None = None) -> Any:
    # The same corner of the box before is the hint (`_nearest_segments`).
    segment = nearest_segments(table, queries, counts, hint_stride=group)
    return signed_distance_to_segments(table, queries, segment, group)


def signed_distance_to_segments(table: SegmentTable, queries: np.ndarray, segment: np.ndarray, group: int = 1) -> Any:
    """Signed planar distance of each point to its given segment, the largest of each `group` of
    consecutive points (NaN passes on).

    Args:
      queries: float32 `(num_points, 3)`, contiguous.
      segment: int64 `(num_points,)`, each point's segment (`nearest_segments`).
    Returns:
      float32 `(num_points // group,)`.
    """
    return _signed_distances(queries, segment, table.sides(), group)


def box_distance_to_road_edge(
    x: np.ndarray,
    y: np.ndarray,
    bottom: np.ndarray,
    length: np.ndarray,
    width: np.ndarray,
    cos_h: np.ndarray,
    sin_h: np.ndarray,
    valid: np.ndarray,
    table: SegmentTable,
    counts: dict | None = None,
) -> np.ndarray:
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
    queries, keep = _box_corner_queries(
        *(by_box(np.asarray(a, _F)) for a in (x, y, bottom, length, width, cos_h, sin_h)), by_box(valid)
    )
    out = np.full((shape[-2], shape[-1], int(np.prod(shape[:-2], dtype=np.int64))), -EXTREMELY_LARGE_DISTANCE, _F)
    out.reshape(-1)[keep] = _signed_distance_groups(table, queries, 4, counts)
    return np.ascontiguousarray(np.moveaxis(out, -1, 0)).reshape(shape)


_box_corners = compiled(box_corners)


@cached_loop
def _box_corner_queries(
    x: Any,
    y: Any,
    bottom: Any,
    length: Any,
    width: Any,
    cos_h: Any,
    sin_h: Any,
    valid: Any,
) -> Any:
    """The 4 corners (x, y, bottom) of each valid box, float32 with 3 columns (4 rows a box), and the valid
    boxes' flat indices, int64, in their flat order; the arguments are arrays of one shape `(...)`."""
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
        queries[4 * i : 4 * i + 4, 2] = bs[k]
    return queries, keep
