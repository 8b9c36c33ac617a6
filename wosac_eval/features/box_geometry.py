"""Oriented boxes in the plane: corners, and signed distance between boxes.

The signed distance between two convex polygons A and B is the signed distance
from the origin to their Minkowski difference A + (-B): negative when they
overlap. For two rectangles the difference is an octagon whose vertex order is
known in closed form: both edge sequences start at their lowest vertex and
merge by angle, so everything is elementwise.

The kernels (`box_corners`, `corner_outline`, `box_outline`,
`minkowski_vertices`, `octagon_signed_distance`) are `ops` kernels: the same
source runs on numpy and JAX arrays and, compiled, in the numpy backend's
search loops (`features.compiled`). A box's corners and outline are separate
values (`x0..x3`, `y0..y3`, ...), so that a scalar can be one. The `..._xy`
and array functions below them lay the corners along a last axis of 4 (or 8).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.features import ops
from wosac_eval.features.float32_math import packet_tail, sincos32
from wosac_eval.features.xp import array_namespace

_F = np.float32
_ZERO, _HALF, _ONE, _MINUS_ONE, _INF = _F(0), _F(0.5), _F(1), _F(-1), _F(np.inf)


def box_corners(x: Any, y: Any, length: Any, width: Any, cos_h: Any, sin_h: Any) -> Any:
    """The 4 corners of upright boxes, counter-clockwise: front-left, rear-left, rear-right, front-right.

    Args:
      x, y, length, width, cos_h, sin_h: float32 `(...)`.
    Returns:
      (x0, x1, x2, x3, y0, y1, y2, y3), float32 `(...)`.
    """
    # Half sizes times the corner's signs (exact), then the official rotation, a small matrix
    # product evaluated with one fused multiply-add per coordinate.
    ahead, behind = length * _HALF * _ONE, length * _HALF * _MINUS_ONE
    left, right = width * _HALF * _ONE, width * _HALF * _MINUS_ONE
    minus_sin = -sin_h
    return (
        ops.fma32(minus_sin, left, cos_h * ahead) + x,
        ops.fma32(minus_sin, left, cos_h * behind) + x,
        ops.fma32(minus_sin, right, cos_h * behind) + x,
        ops.fma32(minus_sin, right, cos_h * ahead) + x,
        ops.fma32(cos_h, left, sin_h * ahead) + y,
        ops.fma32(cos_h, left, sin_h * behind) + y,
        ops.fma32(cos_h, right, sin_h * behind) + y,
        ops.fma32(cos_h, right, sin_h * ahead) + y,
    )


def box_corners_xy(x: Any, y: Any, length: Any, width: Any, cos_h: Any, sin_h: Any) -> Any:
    """`box_corners` with the corners along a last axis: (corners_x, corners_y), float32 `(..., 4)`."""
    xp = array_namespace(x, cos_h)
    c = box_corners(x, y, length, width, cos_h, sin_h)
    return xp.stack(c[:4], axis=-1), xp.stack(c[4:], axis=-1)


def box_bottom_corners(x: Any, y: Any, bottom: Any, length: Any, width: Any, cos_h: Any, sin_h: Any) -> Any:
    """The 4 corners of upright boxes (`box_corners`) at the height `bottom`: float32 `(..., 4, 3)`."""
    xp = array_namespace(x, cos_h)
    cx, cy = box_corners_xy(x, y, length, width, cos_h, sin_h)
    return xp.stack([cx, cy, xp.broadcast_to(bottom[..., None], cx.shape)], axis=-1)


def heading_cos_sin(heading: Any, steps: slice = slice(None), tail: Any = None) -> Any:
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


def _first_lowest(v0: Any, v1: Any, v2: Any, v3: Any) -> Any:
    """Index of the lowest of 4 values, as numpy's argmin picks it: the first minimum, or the first NaN."""
    take = (v1 < v0) | (ops.isnan(v1) & ~ops.isnan(v0))
    at, lowest = ops.where(take, 1, 0), ops.where(take, v1, v0)
    take = (v2 < lowest) | (ops.isnan(v2) & ~ops.isnan(lowest))
    at, lowest = ops.where(take, 2, at), ops.where(take, v2, lowest)
    take = (v3 < lowest) | (ops.isnan(v3) & ~ops.isnan(lowest))
    return ops.where(take, 3, at)


def _from_lowest(x0: Any, x1: Any, x2: Any, x3: Any, y0: Any, y1: Any, y2: Any, y3: Any) -> Any:
    """The corners rotated to start at the lowest one, and the unit direction x, y of the edge leaving it.

    A box of zero size (a logged placeholder state, scored as is in scenario gen) has no edge:
    NaN directions, as officially.
    """
    start = _first_lowest(y0, y1, y2, y3)
    # (start + k) % 4 of these non-negative indices.
    r0, r1, r2, r3 = start, (start + 1) & 3, (start + 2) & 3, (start + 3) & 3
    rx0, rx1, rx2, rx3 = (
        ops.pick4(r0, x0, x1, x2, x3),
        ops.pick4(r1, x0, x1, x2, x3),
        ops.pick4(r2, x0, x1, x2, x3),
        ops.pick4(r3, x0, x1, x2, x3),
    )
    ry0, ry1, ry2, ry3 = (
        ops.pick4(r0, y0, y1, y2, y3),
        ops.pick4(r1, y0, y1, y2, y3),
        ops.pick4(r2, y0, y1, y2, y3),
        ops.pick4(r3, y0, y1, y2, y3),
    )
    ex, ey = rx1 - rx0, ry1 - ry0
    length = ops.sqrt(ex * ex + ey * ey)
    return rx0, rx1, rx2, rx3, ry0, ry1, ry2, ry3, ops.divide(ex, length), ops.divide(ey, length)


def corner_outline(x0: Any, x1: Any, x2: Any, x3: Any, y0: Any, y1: Any, y2: Any, y3: Any) -> Any:
    """What the Minkowski difference needs of one box, from its ccw corners, computed once per box.

    Returns:
      20 values `(...)`: the corners from the lowest one and the unit direction of the edge leaving
      it, of the box (as A: 10 values), then of the box negated (as B: 10 values).
    """
    a = _from_lowest(x0, x1, x2, x3, y0, y1, y2, y3)
    b = _from_lowest(-x0, -x1, -x2, -x3, -y0, -y1, -y2, -y3)
    return (
        a[0],
        a[1],
        a[2],
        a[3],
        a[4],
        a[5],
        a[6],
        a[7],
        a[8],
        a[9],
        b[0],
        b[1],
        b[2],
        b[3],
        b[4],
        b[5],
        b[6],
        b[7],
        b[8],
        b[9],
    )


def box_outline(x: Any, y: Any, length: Any, width: Any, cos_h: Any, sin_h: Any) -> Any:
    """`corner_outline` of upright boxes (`box_corners`)."""
    x0, x1, x2, x3, y0, y1, y2, y3 = box_corners(x, y, length, width, cos_h, sin_h)
    return corner_outline(x0, x1, x2, x3, y0, y1, y2, y3)


def _merged_vertex(j: Any, a: Any, b: Any, b_turns_left: Any) -> Any:
    """Vertex j (0..7) of A + (-B) from the outlines: both edge sequences start at their lowest vertex
    and merge by angle; whose edge comes first depends on the turn between the lowest edges."""
    a_order = (0, 0, 1, 1, 2, 2, 3, 3)[j]
    b_order = (0, 1, 1, 2, 2, 3, 3, 0)[j]
    # B's outline is of the box negated: its corners come negated already.
    return (
        ops.where(b_turns_left, a[b_order], a[a_order]) + ops.where(b_turns_left, b[10 + a_order], b[10 + b_order]),
        ops.where(b_turns_left, a[4 + b_order], a[4 + a_order])
        + ops.where(b_turns_left, b[14 + a_order], b[14 + b_order]),
    )


def minkowski_vertices(a: Any, b: Any) -> Any:
    """Vertices of A + (-B), counter-clockwise, from `corner_outline`s of A and B (broadcast together).

    Returns:
      (x0, ..., x7, y0, ..., y7), float32 `(...)`.
    """
    b_turns_left = (a[8] * b[19] - a[9] * b[18]) >= _ZERO
    x0, y0 = _merged_vertex(0, a, b, b_turns_left)
    x1, y1 = _merged_vertex(1, a, b, b_turns_left)
    x2, y2 = _merged_vertex(2, a, b, b_turns_left)
    x3, y3 = _merged_vertex(3, a, b, b_turns_left)
    x4, y4 = _merged_vertex(4, a, b, b_turns_left)
    x5, y5 = _merged_vertex(5, a, b, b_turns_left)
    x6, y6 = _merged_vertex(6, a, b, b_turns_left)
    x7, y7 = _merged_vertex(7, a, b, b_turns_left)
    return x0, x1, x2, x3, x4, x5, x6, x7, y0, y1, y2, y3, y4, y5, y6, y7


def _edge_to_origin(x0: Any, y0: Any, x1: Any, y1: Any) -> Any:
    """For the polygon edge from vertex 0 to vertex 1: (whether the origin is on its inner side,
    the distance from the origin to the edge where it projects onto it, else +inf, and the squared
    distance from the origin to vertex 0)."""
    ex, ey = x1 - x0, y1 - y0
    edge_length = ops.sqrt(ex * ex + ey * ey)
    tx, ty = ops.divide(ex, edge_length), ops.divide(ey, edge_length)
    # Vector from the vertex to the query point (the origin).
    vx, vy = _ZERO - x0, _ZERO - y0
    # Positive on the outward side of the edge (outward normal is (ty, -tx)).
    signed_perpendicular = ty * vx + (-tx) * vy
    along = ops.divide(tx * vx + ty * vy, edge_length)
    on_edge = (along >= _ZERO) & (along <= _ONE)
    edge_distance = ops.where(on_edge, ops.absolute(signed_perpendicular), _INF)
    return signed_perpendicular <= _ZERO, edge_distance, vx * vx + vy * vy


def octagon_signed_distance(m: Any) -> Any:
    """Signed distance from the origin to convex ccw octagons (negative inside), float32 `(...)`.

    Args:
      m: (x0, ..., x7, y0, ..., y7), the vertices (`minkowski_vertices`).
    """
    x0, x1, x2, x3, x4, x5, x6, x7 = m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7]
    y0, y1, y2, y3, y4, y5, y6, y7 = m[8], m[9], m[10], m[11], m[12], m[13], m[14], m[15]
    in0, e0, v0 = _edge_to_origin(x0, y0, x1, y1)
    in1, e1, v1 = _edge_to_origin(x1, y1, x2, y2)
    in2, e2, v2 = _edge_to_origin(x2, y2, x3, y3)
    in3, e3, v3 = _edge_to_origin(x3, y3, x4, y4)
    in4, e4, v4 = _edge_to_origin(x4, y4, x5, y5)
    in5, e5, v5 = _edge_to_origin(x5, y5, x6, y6)
    in6, e6, v6 = _edge_to_origin(x6, y6, x7, y7)
    in7, e7, v7 = _edge_to_origin(x7, y7, x0, y0)
    inside = ((in0 & in1) & (in2 & in3)) & ((in4 & in5) & (in6 & in7))
    # The nearest of the edges and vertices, a minimum passing NaN on (all are +0 or more: the order
    # does not change it). The vertices' square roots are one: the square root is correctly rounded
    # and monotone, so the root of the least square is the least of the roots.
    edge = ops.minimum(
        ops.minimum(ops.minimum(e0, e4), ops.minimum(e2, e6)), ops.minimum(ops.minimum(e1, e5), ops.minimum(e3, e7))
    )
    vertex = ops.minimum(
        ops.minimum(ops.minimum(v0, v4), ops.minimum(v2, v6)), ops.minimum(ops.minimum(v1, v5), ops.minimum(v3, v7))
    )
    nearest = ops.minimum(edge, ops.sqrt(vertex))
    return ops.where(inside, -nearest, nearest)


def minkowski_difference(ax: Any, ay: Any, bx: Any, by: Any) -> Any:
    """Vertices of A + (-B) for boxes given by ccw corners, counter-clockwise.

    Args:
      ax, ay, bx, by: float32 `(..., 4)`.
    Returns:
      (mx, my), float32 `(..., 8)`.
    """
    xp = array_namespace(ax, bx)
    corners = lambda px, py: tuple(px[..., k] for k in range(4)) + tuple(py[..., k] for k in range(4))  # noqa: E731
    m = minkowski_vertices(corner_outline(*corners(ax, ay)), corner_outline(*corners(bx, by)))
    return xp.stack(m[:8], axis=-1), xp.stack(m[8:], axis=-1)


def origin_signed_distance(px: Any, py: Any) -> Any:
    """Signed distance from the origin to convex ccw octagons (negative inside), such as
    `minkowski_difference`'s.

    Args:
      px, py: float32 `(..., 8)`.
    Returns:
      float32 `(...)`.
    """
    if px.shape[-1] != 8:
        raise ValueError(f"origin_signed_distance takes octagons, not polygons of {px.shape[-1]} vertices")
    return octagon_signed_distance(tuple(px[..., k] for k in range(8)) + tuple(py[..., k] for k in range(8)))
