"""The road-edge segment table: official order, the signed-distance kernels, the bucket grid.

Road edges are polylines with the road on their left. For each query point the
relevant segment is the nearest one in 3D, with heights stretched 3x
(`Z_STRETCH`) so that a road edge on another level (a bridge) is not picked; the
returned distance is the planar distance to that segment, negative on the road
side. Where the point projects past a segment end, the sign follows the
convexity of the corner between the segment and its neighbour (`corner_sign`).

`build_segment_table` flattens a scenario's road edges once, padded as the
official code pads them, with each segment's neighbours and corner convexity,
and lists the valid segments in planar buckets of `BUCKET_SIDE` (8 m; doubled
until a large map needs at most `_MAX_BUCKETS`). The float32 kernels here
(`segment_distances`, `side_of_segment`, `corner_sign`) run on numpy, JAX and,
compiled, in the search loops; the float64 helpers at the end walk the bucket
grid ring by ring for both searches built on it: `pruned_search` (numpy) and
`cell_tables` (the candidate tables of the fixed-shape device search).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple, SupportsFloat

import numba
import numpy as np

from wosac_eval.features import ops
from wosac_eval.features.spatial import column_bounds, finite_rows, pad_polylines

_F = np.float32
EXTREMELY_LARGE_DISTANCE = _F(1e10)
OFFROAD_DISTANCE_THRESHOLD = 0.0
Z_STRETCH = 3.0
_Z_STRETCH32 = _F(Z_STRETCH)
CYCLIC_TOLERANCE_M2 = 1.0
BUCKET_SIDE = 8.0  # metres: the planar buckets listing the segments that cross them
_GRID_BORDER = 256.0  # metres of buckets around the road edges' box: cells there get candidate lists
_MAX_BUCKETS = 1 << 20  # larger maps get larger buckets (the grid's memory stays bounded)


@dataclasses.dataclass(frozen=True)
class SegmentTable:
    """Road-edge segments flattened in the official (polyline, segment) order.

    Polylines are padded to the longest one, as the official code does; padding
    segments are invalid. Attributes are `(num_segments,)` or `(num_segments, 3)`,
    then the planar bucket grid of the searches (`bucket_grid`).
    """

    start: np.ndarray  # float32 (S, 3)
    delta: np.ndarray  # float32 (S, 3): end - start
    valid: np.ndarray  # bool (S,)
    prior: np.ndarray  # int64 (S,): neighbour used when projecting before the start
    next: np.ndarray  # int64 (S,): neighbour used when projecting past the end
    prior_valid: np.ndarray  # bool (S,)
    next_valid: np.ndarray  # bool (S,)
    convex_before: np.ndarray  # bool (S,): left turn from the prior segment into this one
    convex_after: np.ndarray  # bool (S,): left turn from this segment into the next
    length: np.ndarray  # float64 (S,): |delta_xy| + 3 |delta_z|, for the float32 rounding margins
    frame: np.ndarray  # float64 (S, 7): start x, y, unit direction x, y, planar length, lowest and
    # highest z (`pruned_search._distance_bound`)
    bucket_origin: np.ndarray  # float64 (2,): the grid's lower corner
    bucket_side: float  # metres
    bucket_shape: np.ndarray  # int64 (2,): buckets along x, y; then those holding segments:
    segment_buckets: np.ndarray  # int64 (4,): first and last bucket along x, then along y
    bucket_start: np.ndarray  # int64 (num_buckets + 1,): where each bucket's list begins in
    bucket_segments: np.ndarray  # int32: valid segments crossing each bucket, bucket by bucket

    def sides(self) -> SegmentSides:
        """The arrays the compiled signed distance reads."""
        return SegmentSides(
            self.start,
            self.delta,
            self.valid,
            self.prior,
            self.next,
            self.prior_valid,
            self.next_valid,
            self.convex_before,
            self.convex_after,
        )

    def searched(self) -> SearchedSegments:
        """The arrays the compiled searches read."""
        return SearchedSegments(self.start, self.delta, self.frame, self.length)

    def buckets(self) -> Buckets:
        """The bucket grid as the compiled searches read it."""
        names = ("bucket_origin", "bucket_side", "bucket_shape", "segment_buckets", "bucket_start", "bucket_segments")
        return search_buckets({k: getattr(self, k) for k in names})


def _cross(ax: Any, ay: Any, bx: Any, by: Any) -> Any:
    return ax * by - ay * bx


def segment_frames(start: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """float64 `(num_segments, 7)`: each segment's start (x, y), planar unit direction (x, y), planar length, and
    lowest and highest z; a segment of no planar length gets the direction (1, 0) (`pruned_search._distance_bound`)."""
    dx, dy = delta[:, 0].astype(np.float64), delta[:, 1].astype(np.float64)
    length = np.hypot(dx, dy)
    has = length > 0
    ux = np.where(has, dx / np.where(has, length, 1.0), 1.0)
    uy = np.where(has, dy / np.where(has, length, 1.0), 0.0)
    z0 = start[:, 2].astype(np.float64)
    z1 = z0 + delta[:, 2]
    return np.stack(
        [
            start[:, 0].astype(np.float64),
            start[:, 1].astype(np.float64),
            ux,
            uy,
            length,
            np.minimum(z0, z1),
            np.maximum(z0, z1),
        ],
        axis=1,
    )


def build_segment_table(polylines: Iterable[np.ndarray]) -> SegmentTable:
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
        start=start,
        delta=delta,
        valid=valid_flat,
        prior=prior,
        next=nxt,
        prior_valid=valid_flat[prior],
        next_valid=valid_flat[nxt],
        convex_before=convex_before.reshape(-1),
        convex_after=convex_after.reshape(-1),
        length=np.hypot(delta[:, 0].astype(np.float64), delta[:, 1])
        + Z_STRETCH * np.abs(delta[:, 2].astype(np.float64)),
        frame=segment_frames(start, delta),
        **bucket_grid(start, delta, valid_flat),
    )


def segment_distances(
    px: Any,
    py: Any,
    pz: Any,
    sx: Any,
    sy: Any,
    sz: Any,
    dx: Any,
    dy: Any,
    dz: Any,
) -> Any:
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


def segment_side(query_xy: Any, start: Any, delta: Any) -> Any:
    """Sign of the cross product: +1 on the right (off-road) side of a segment.

    Args:
      query_xy: float32 `(..., 2)`; start, delta: float32 `(..., 3)` (or `(..., 2)`).
    Returns:
      float32 `(...)` in {-1, 0, 1}.
    """
    return side_of_segment(
        query_xy[..., 0], query_xy[..., 1], start[..., 0], start[..., 1], delta[..., 0], delta[..., 1]
    )


def side_of_segment(px: Any, py: Any, sx: Any, sy: Any, dx: Any, dy: Any) -> Any:
    """`segment_side` on separate coordinates (an elementwise `ops` kernel)."""
    return ops.sign((px - sx) * dy - (py - sy) * dx)


def corner_sign(
    rel_t: Any,
    n: Any,
    n_prior: Any,
    n_next: Any,
    convex_before: Any,
    convex_after: Any,
    prior_valid: Any,
    next_valid: Any,
) -> Any:
    """Side of the nearest segment, corrected where the point projects past an end.

    Past an end the sign follows the corner with the neighbour segment: on a
    convex corner the point is off-road if it is on the right of either
    segment, on a concave one only if it is on the right of both.
    An elementwise `ops` kernel: all arguments are `(...)` arrays or scalars.
    """
    before = ops.where(convex_before, ops.maximum(n, n_prior), ops.minimum(n, n_prior))
    after = ops.where(convex_after, ops.maximum(n, n_next), ops.minimum(n, n_next))
    return ops.where((rel_t < _F(0)) & prior_valid, before, ops.where((rel_t > _F(1)) & next_valid, after, n))


# --- The bucket grid of the compiled searches -----------------------------------------------------


def bucket_grid(start: np.ndarray, delta: np.ndarray, valid: np.ndarray) -> dict:
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
    bucket_start, bucket_segments, occupied = _bucket_lists(
        start, delta, listed, origin[0], origin[1], side, shape[0], shape[1]
    )
    return {
        "bucket_origin": origin,
        "bucket_side": side,
        "bucket_shape": shape,
        "segment_buckets": occupied,
        "bucket_start": bucket_start,
        "bucket_segments": bucket_segments,
    }


class SearchedSegments(NamedTuple):
    """The segment arrays the compiled searches read, a `SegmentTable`'s (`SegmentTable.searched`).

    Attributes:
      start, delta: float32 `(num_segments, 3)`; frame: float64 `(num_segments, 7)` (`segment_frames`);
        length: float64 `(num_segments,)`.
    """

    start: np.ndarray
    delta: np.ndarray
    frame: np.ndarray
    length: np.ndarray


class SegmentSides(NamedTuple):
    """The segment arrays the compiled signed distance reads (which side of a segment and of its corners
    a point is on), a `SegmentTable`'s (`SegmentTable.sides`): see there."""

    start: np.ndarray
    delta: np.ndarray
    valid: np.ndarray
    prior: np.ndarray
    next: np.ndarray
    prior_valid: np.ndarray
    next_valid: np.ndarray
    convex_before: np.ndarray
    convex_after: np.ndarray


class Buckets(NamedTuple):
    """The bucket grid as the compiled loops read it.

    Attributes:
      grid: `search_grid`'s tuple of 9 (origin, side, buckets along x and y, the occupied range).
      start: int64 `(num_buckets + 1,)`; segments: int32: each bucket's segments,
        `segments[start[b]:start[b + 1]]`.
    """

    grid: tuple
    start: np.ndarray
    segments: np.ndarray


class Gather(NamedTuple):
    """The workspace of segments gathered ring by ring (`gather_ring`).

    Attributes:
      seen: int64 `(num_segments,)`, the tag under which each segment was last gathered.
      ring: the buckets of one ring (`ring_buffer`).
      segment: int32 `(num_segments,)`, the gathered segments; key: float64 `(num_segments,)`, their planar distances.
    """

    seen: np.ndarray
    ring: np.ndarray
    segment: np.ndarray
    key: np.ndarray


@numba.njit
def gather_workspace(num_segments: Any, grid: Any) -> Any:
    """A `Gather` for `num_segments` segments of the grid, no segment seen yet."""
    return Gather(
        np.full(num_segments, -1, np.int64),
        ring_buffer(grid),
        np.empty(num_segments, np.int32),
        np.empty(num_segments, np.float64),
    )


def search_buckets(grid: Mapping) -> Buckets:
    """The `Buckets` of `bucket_grid`'s arrays (which a `SegmentTable` carries too: `SegmentTable.buckets`)."""
    origin, side, shape, occupied = (
        grid[k] for k in ("bucket_origin", "bucket_side", "bucket_shape", "segment_buckets")
    )
    return Buckets(search_grid(origin, side, shape, occupied), grid["bucket_start"], grid["bucket_segments"])


def search_grid(origin: np.ndarray, side: SupportsFloat, shape: np.ndarray, occupied: np.ndarray) -> tuple:
    """The bucket grid as the compiled loops read it, a tuple of 9: origin x, origin y and side (float), buckets
    along x and y, then the first and last bucket holding a segment along x and along y (int); from the
    `bucket_origin`, `bucket_side`, `bucket_shape` and `segment_buckets` of `bucket_grid` or a `SegmentTable`."""
    return (*(float(v) for v in origin), float(side), *(int(v) for v in shape), *(int(v) for v in occupied))


@numba.njit(cache=True)
def _bucket_lists(
    start: Any, delta: Any, listed: Any, origin_x: Any, origin_y: Any, side: Any, num_x: Any, num_y: Any
) -> Any:
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
def ring_buffer(grid: Any) -> np.ndarray:
    """Room for the buckets of one ring within the grid's occupied range (`ring_buckets`)."""
    origin_x, origin_y, side, num_x, num_y, x0, x1, y0, y1 = grid
    return np.empty(2 * (max(x1 - x0, 0) + max(y1 - y0, 0)) + 4, np.int64)


@numba.njit
def rings_around(x: Any, y: Any, grid: Any) -> Any:
    """The bucket (bi, bj) of a point and the first and last rings around it that meet the
    occupied range (`ring_buckets`)."""
    origin_x, origin_y, side, num_x, num_y, x0, x1, y0, y1 = grid
    bi, bj = bucket_of(x, origin_x, side), bucket_of(y, origin_y, side)
    return bi, bj, max(0, x0 - bi, bi - x1, y0 - bj, bj - y1), max(x1 - bi, bi - x0, y1 - bj, bj - y0)


@numba.njit
def ring_buckets(bi: Any, bj: Any, r: Any, grid: Any, out: Any) -> Any:
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
def bucket_of(value: Any, origin: Any, side: Any) -> Any:
    """The bucket index along one axis of a finite coordinate (`bucket_coordinate`'s floor)."""
    return int(math.floor(bucket_coordinate(value, origin, side)))


@numba.njit
def bucket_coordinate(value: Any, origin: Any, side: Any) -> Any:
    """Where a finite coordinate lies along one axis, in buckets from the grid's origin, clamped far
    beyond any grid (an integer conversion of a huge float is undefined). The side is a power of two
    (`bucket_grid`): multiplying by its inverse (hoisted out of callers' loops) is exact, where a
    division per coordinate was most of `cell_lists.query_cells`' time."""
    return min(max((value - origin) * (1.0 / side), -1e15), 1e15)


@numba.njit
def _bucket_range(start: Any, delta: Any, origin: Any, side: Any, num: Any) -> Any:
    """Buckets along one axis overlapped by a segment (clamped to the grid)."""
    low, high = min(start, start + delta), max(start, start + delta)
    first = bucket_of(np.float64(low), origin, side)
    last = bucket_of(np.float64(high), origin, side)
    return max(0, min(first, num - 1)), max(0, min(last, num - 1))


@numba.njit
def planar_squared(qx: Any, qy: Any, k: int, frame: Any) -> Any:
    """The squared planar distance (float64) from a point to segment k, in the segment's own frame (no
    division). Its rounding, about 1e-16 of the coordinates, is far inside `cell_lists.rounding_margin`."""
    tx, ty = qx - frame[k, 0], qy - frame[k, 1]
    along = tx * frame[k, 2] + ty * frame[k, 3]
    across = tx * frame[k, 3] - ty * frame[k, 2]
    beyond = max(-along, along - frame[k, 4], 0.0)
    return beyond * beyond + across * across


@numba.njit
def planar_distance(cx: Any, cy: Any, k: int, frame: Any) -> Any:
    """Planar distance (float64) from a point to segment k: a lower bound of its selection distance."""
    return math.sqrt(planar_squared(cx, cy, k, frame))


@numba.njit
def gather_ring(cx: Any, cy: Any, r: Any, frame: Any, buckets: Buckets, gather: Any, tag: Any, n: Any) -> Any:
    """Appends the segments of the buckets r rings around the bucket of (cx, cy) not met yet (`gather.seen`
    is not `tag`), with their planar distance from (cx, cy), to `gather.segment` and `gather.key` from `n`;
    returns the new count. Before ring r, a segment not met yet is at least (r - 1) buckets away."""
    grid, ring = buckets.grid, gather.ring
    bi, bj = bucket_of(cx, grid[0], grid[2]), bucket_of(cy, grid[1], grid[2])  # as `rings_around` finds them
    for q in range(ring_buckets(bi, bj, r, grid, ring)):
        for p in range(buckets.start[ring[q]], buckets.start[ring[q] + 1]):
            k = buckets.segments[p]
            if gather.seen[k] != tag:
                gather.seen[k] = tag
                gather.segment[n], gather.key[n] = k, planar_distance(cx, cy, k, frame)
                n += 1
    return n
