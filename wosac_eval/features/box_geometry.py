"""Oriented boxes in the plane: corners, and signed distance between boxes.

The signed distance between two convex polygons A and B is the signed distance
from the origin to their Minkowski difference A + (-B): negative when they
overlap. For two rectangles the difference is an octagon whose vertex order is
known in closed form, which keeps everything vectorised.
"""
from __future__ import annotations

import numpy as np

from wosac_eval.features.float32_math import fma32, packet_tail, sincos32

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


def heading_cos_sin(heading: np.ndarray, steps: slice = slice(None)):
    """cos and sin of headings, rounded as the official box-corner code rounds them.

    Args:
      heading: float32 `(..., num_objects, num_steps)`, the full official tensor
        of one rollout per leading index.
      steps: the steps to return.
    Returns:
      (cos, sin), float32 `(..., num_objects, len(steps))`.
    """
    tail = packet_tail(heading.shape[-2:])[:, steps]
    sin, cos = sincos32(heading[..., steps], tail)
    return cos, sin


def _norm2(a, b):
    return np.sqrt(a * a + b * b)


_NEXT_VERTEX = np.array([1, 2, 3, 0])


def _downmost_edge(px, py):
    """Index of the lowest vertex `(...)` and the unit direction `(...)` of the edge leaving it.

    Args:
      px, py: float32 `(..., 4)`, contiguous.
    """
    start = np.argmin(py, axis=-1)
    rows = np.arange(start.size).reshape(start.shape) * 4
    first, second = rows + start, rows + _NEXT_VERTEX[start]
    ex = np.take(px, second) - np.take(px, first)
    ey = np.take(py, second) - np.take(py, first)
    length = _norm2(ex, ey)
    return start, ex / length, ey / length


_ORDER_A = np.array([0, 0, 1, 1, 2, 2, 3, 3])
_ORDER_B = np.array([0, 1, 1, 2, 2, 3, 3, 0])
# Vertex orders by (whether B's lowest edge turns left of A's, lowest vertex):
# _MERGE_A[t, k] is the order of A's vertices, _MERGE_B[t, k] of B's.
_MERGE_A = np.stack([(_ORDER_A + k) % 4 for k in range(4)] + [(_ORDER_B + k) % 4 for k in range(4)]).reshape(2, 4, 8)
_MERGE_B = np.stack([(_ORDER_B + k) % 4 for k in range(4)] + [(_ORDER_A + k) % 4 for k in range(4)]).reshape(2, 4, 8)


def minkowski_difference(ax, ay, bx, by):
    """Vertices of A + (-B) for boxes given by ccw corners, counter-clockwise.

    Args:
      ax, ay, bx, by: float32 `(..., 4)`.
    Returns:
      (mx, my), float32 `(..., 8)`.
    """
    nbx, nby = -bx, -by
    a_start, a_dx, a_dy = _downmost_edge(ax, ay)
    b_start, b_dx, b_dy = _downmost_edge(nbx, nby)
    # Merge the two edge sequences by angle, starting from the lowest vertices;
    # whose edge comes first depends on the turn between the lowest edges.
    b_turns_left = ((a_dx * b_dy - a_dy * b_dx) >= 0).astype(np.intp)
    rows = (np.arange(b_turns_left.size).reshape(b_turns_left.shape) * 4)[..., None]
    a_index = _MERGE_A[b_turns_left, a_start] + rows
    b_index = _MERGE_B[b_turns_left, b_start] + rows
    mx = np.take(ax, a_index) + np.take(nbx, b_index)
    my = np.take(ay, a_index) + np.take(nby, b_index)
    return mx, my


def _fold(values, pairwise):
    """Reduces the last axis by halving it with `pairwise` (faster than a reduction along a short last axis).

    For min / and the result is the same as `np.min` / `np.all`, whatever the order.
    """
    while values.shape[-1] > 1:
        half = values.shape[-1] // 2
        odd = values[..., 2 * half:]
        values = pairwise(values[..., :half], values[..., half:2 * half])
        if odd.shape[-1]:
            values = np.concatenate([values, odd], axis=-1)
    return values[..., 0]


def origin_signed_distance(px, py):
    """Signed distance from the origin to convex ccw polygons (negative inside).

    Args:
      px, py: float32 `(..., num_vertices)`.
    Returns:
      float32 `(...)`.
    """
    ex = np.roll(px, -1, axis=-1) - px
    ey = np.roll(py, -1, axis=-1) - py
    edge_length = _norm2(ex, ey)
    tx, ty = ex / edge_length, ey / edge_length
    # Vector from each vertex to the query point (the origin).
    vx, vy = _F(0) - px, _F(0) - py
    vertex_distance = _norm2(vx, vy)
    # Positive on the outward side of each edge (outward normal is (ty, -tx)).
    signed_perpendicular = ty * vx + (-tx) * vy
    inside = _fold(signed_perpendicular <= 0, np.logical_and)
    along = (tx * vx + ty * vy) / edge_length
    on_edge = (along >= 0) & (along <= 1)
    edge_distance = np.where(on_edge, np.abs(signed_perpendicular), _F(np.inf))
    nearest = _fold(np.minimum(edge_distance, vertex_distance), np.minimum)
    return np.where(inside, -nearest, nearest)
