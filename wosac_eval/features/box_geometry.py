"""Oriented boxes in the plane: corners, and signed distance between boxes.

The signed distance between two convex polygons A and B is the signed distance
from the origin to their Minkowski difference A + (-B): negative when they
overlap. For two rectangles the difference is an octagon whose vertex order is
known in closed form, which keeps everything vectorised. The functions take
numpy or JAX arrays.
"""
from __future__ import annotations

import numpy as np

from wosac_eval.features.float32_math import fma32, packet_tail, sincos32
from wosac_eval.features.xp import array_namespace, divide, errstate

_F = np.float32
# Counter-clockwise corner signs (front-left, rear-left, rear-right, front-right).
_LONG_SIGN = np.array([1, -1, -1, 1], dtype=_F)
_LAT_SIGN = np.array([1, 1, -1, -1], dtype=_F)


def box_corners_xy(x, y, length, width, cos_h, sin_h):
    """The 4 corners of upright boxes, counter-clockwise.

    Args:
      x, y, length, width, cos_h, sin_h: float32 `(...)`.
    Returns:
      (corners_x, corners_y), float32 `(..., 4)`.
    """
    half_l = (length * _F(0.5))[..., None] * _LONG_SIGN
    half_w = (width * _F(0.5))[..., None] * _LAT_SIGN
    c, s = cos_h[..., None], sin_h[..., None]
    # The official rotation is a small matrix product, evaluated with one
    # fused multiply-add per coordinate.
    cx = fma32(-s, half_w, c * half_l) + x[..., None]
    cy = fma32(c, half_w, s * half_l) + y[..., None]
    return cx, cy


def heading_cos_sin(heading, steps: slice = slice(None), tail=None):
    """cos and sin of headings, rounded as the official box-corner code rounds them.

    Args:
      heading: float32 `(..., num_objects, num_steps)`, the full official tensor
        of one rollout per leading index.
      steps: the steps to return.
      tail: the official op's trailing-packet mask `(num_objects, len(steps))`,
        when `heading` is padded beyond the official shape (JAX buckets).
    Returns:
      (cos, sin), float32 `(..., num_objects, len(steps))`.
    """
    if tail is None:
        tail = packet_tail(heading.shape[-2:])[:, steps]
    sin, cos = sincos32(heading[..., steps], tail)
    return cos, sin


def _norm2(a, b):
    return array_namespace(a, b).sqrt(a * a + b * b)


_NEXT_VERTEX = np.array([1, 2, 3, 0], np.int32)  # int32 index tables: also with JAX x64 off


def _downmost_edge(px, py):
    """Index of the lowest vertex `(...)` and the unit direction `(...)` of the edge leaving it.

    Args:
      px, py: float32 `(..., 4)`, contiguous.
    """
    xp = array_namespace(px, py)
    start = xp.argmin(py, axis=-1)
    rows = xp.arange(start.size).reshape(start.shape) * 4
    first, second = rows + start, rows + xp.asarray(_NEXT_VERTEX)[start]
    ex = xp.take(px, second) - xp.take(px, first)
    ey = xp.take(py, second) - xp.take(py, first)
    length = _norm2(ex, ey)
    # A box of zero size (a logged placeholder state, scored as is in scenario gen) has no edge:
    # NaN directions, as officially.
    with errstate(xp, invalid="ignore", divide="ignore"):
        return start, divide(ex, length), divide(ey, length)


_ORDER_A = np.array([0, 0, 1, 1, 2, 2, 3, 3], np.int32)
_ORDER_B = np.array([0, 1, 1, 2, 2, 3, 3, 0], np.int32)
# Vertex orders by (whether B's lowest edge turns left of A's, lowest vertex):
# _MERGE_A[t, k] is the order of A's vertices, _MERGE_B[t, k] of B's.
_MERGE_A = np.stack([(_ORDER_A + k) % 4 for k in range(4)] + [(_ORDER_B + k) % 4 for k in range(4)]).reshape(2, 4, 8)
_MERGE_B = np.stack([(_ORDER_B + k) % 4 for k in range(4)] + [(_ORDER_A + k) % 4 for k in range(4)]).reshape(2, 4, 8)


def outline(px, py):
    """What the Minkowski difference needs of one box, computed once per box.

    Args:
      px, py: float32 `(..., 4)` ccw corners, contiguous.
    Returns:
      (px, py, lowest vertex, its edge's unit direction x, y: the box as A),
      then (lowest vertex, edge direction x, y of the box negated: the box as B);
      the last six are `(...)`.
    """
    return (px, py, *_downmost_edge(px, py), *_downmost_edge(-px, -py))


def minkowski_difference_of(a, b):
    """Vertices of A + (-B), counter-clockwise, from `outline`s of A and B (broadcast together).

    Returns:
      (mx, my), float32 `(..., 8)`.
    """
    ax, ay, a_start, a_dx, a_dy = a[:5]
    bx, by, b_start, b_dx, b_dy = b[0], b[1], *b[5:]
    xp = array_namespace(ax, ay, bx, by)
    nbx, nby = -bx, -by
    # Merge the two edge sequences by angle, starting from the lowest vertices;
    # whose edge comes first depends on the turn between the lowest edges.
    b_turns_left = ((a_dx * b_dy - a_dy * b_dx) >= 0).astype(np.int32)  # int32: also with JAX x64 off
    rows = (xp.arange(b_turns_left.size).reshape(b_turns_left.shape) * 4)[..., None]
    a_index = xp.asarray(_MERGE_A)[b_turns_left, a_start] + rows
    b_index = xp.asarray(_MERGE_B)[b_turns_left, b_start] + rows
    mx = xp.take(ax, a_index) + xp.take(nbx, b_index)
    my = xp.take(ay, a_index) + xp.take(nby, b_index)
    return mx, my


def minkowski_difference(ax, ay, bx, by):
    """Vertices of A + (-B) for boxes given by ccw corners, counter-clockwise.

    Args:
      ax, ay, bx, by: float32 `(..., 4)`.
    Returns:
      (mx, my), float32 `(..., 8)`.
    """
    return minkowski_difference_of(outline(ax, ay), outline(bx, by))


def _fold(values, pairwise):
    """Reduces the last axis by halving it with `pairwise` (faster than a reduction along a short last axis).

    For min / and the result is the same as `np.min` / `np.all`, whatever the order.
    """
    xp = array_namespace(values)
    while values.shape[-1] > 1:
        half = values.shape[-1] // 2
        odd = values[..., 2 * half:]
        values = pairwise(values[..., :half], values[..., half:2 * half])
        if odd.shape[-1]:
            values = xp.concatenate([values, odd], axis=-1)
    return values[..., 0]


def origin_signed_distance(px, py):
    """Signed distance from the origin to convex ccw polygons (negative inside).

    Args:
      px, py: float32 `(..., num_vertices)`.
    Returns:
      float32 `(...)`.
    """
    xp = array_namespace(px, py)
    ex = xp.roll(px, -1, axis=-1) - px
    ey = xp.roll(py, -1, axis=-1) - py
    edge_length = _norm2(ex, ey)
    tx, ty = divide(ex, edge_length), divide(ey, edge_length)
    # Vector from each vertex to the query point (the origin).
    vx, vy = _F(0) - px, _F(0) - py
    vertex_distance = _norm2(vx, vy)
    # Positive on the outward side of each edge (outward normal is (ty, -tx)).
    signed_perpendicular = ty * vx + (-tx) * vy
    inside = _fold(signed_perpendicular <= 0, xp.logical_and)
    along = divide(tx * vx + ty * vy, edge_length)
    on_edge = (along >= 0) & (along <= 1)
    edge_distance = xp.where(on_edge, xp.abs(signed_perpendicular), _F(np.inf))
    nearest = _fold(xp.minimum(edge_distance, vertex_distance), xp.minimum)
    return xp.where(inside, -nearest, nearest)
