"""Small planar geometry helpers for the synthetic scene generator and the baselines.

Polylines are float arrays of shape `(num_points, 2)`; headings are radians,
counter-clockwise from +x (East), as in WOMD.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Wraps angles to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def rotation(theta: float) -> np.ndarray:
    """2x2 matrix rotating column vectors by `theta` (counter-clockwise)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def arc_lengths(polyline: np.ndarray) -> np.ndarray:
    """Cumulative arc length at each vertex, shape `(num_points,)`."""
    seg = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def resample(polyline: np.ndarray, spacing: float) -> np.ndarray:
    """Resamples a polyline at (nearly) constant `spacing`, keeping both end points."""
    s = arc_lengths(polyline)
    n = max(int(np.ceil(s[-1] / spacing)), 1)
    targets = np.linspace(0.0, s[-1], n + 1)
    return np.stack([np.interp(targets, s, polyline[:, k]) for k in range(polyline.shape[1])], axis=1)


def segment(start: ArrayLike, end: ArrayLike, spacing: float) -> np.ndarray:
    """Straight polyline from `start` to `end` sampled every ~`spacing` metres."""
    return resample(np.stack([np.asarray(start, float), np.asarray(end, float)]), spacing)


def bezier(p0: np.ndarray, d0: np.ndarray, p1: np.ndarray, d1: np.ndarray, spacing: float) -> np.ndarray:
    """Cubic Bezier leaving `p0` along unit direction `d0`, arriving at `p1` along `d1`.

    Used for the connector lanes that turn through an intersection; the control
    arms are ~0.55 of the chord, which approximates a circular arc for right angles.
    """
    p0, d0, p1, d1 = (np.asarray(a, float) for a in (p0, d0, p1, d1))
    arm = 0.55 * np.linalg.norm(p1 - p0)
    c0, c1 = p0 + arm * d0, p1 - arm * d1
    t = np.linspace(0.0, 1.0, 200)[:, None]
    dense = (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * c0 + 3 * (1 - t) * t**2 * c1 + t**3 * p1
    return resample(dense, spacing)


def arc(center: ArrayLike, radius: float, angle_from: float, angle_to: float, spacing: float) -> np.ndarray:
    """Circular arc from `angle_from` to `angle_to` (either direction), shape `(num_points, 2)`."""
    n = max(int(np.ceil(abs(angle_to - angle_from) * radius / spacing)), 2)
    a = np.linspace(angle_from, angle_to, n + 1)
    return np.asarray(center, float) + radius * np.stack([np.cos(a), np.sin(a)], axis=1)


def tangents(polyline: np.ndarray) -> np.ndarray:
    """Unit tangent at each vertex (central differences), shape `(num_points, 2)`."""
    d = np.gradient(polyline, axis=0)
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)


def left_normals(polyline: np.ndarray) -> np.ndarray:
    """Unit normal pointing to the left of travel at each vertex, shape `(num_points, 2)`."""
    t = tangents(polyline)
    return np.stack([-t[:, 1], t[:, 0]], axis=1)


def box_corners(x: np.ndarray, y: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """Corners of oriented boxes, shape `(..., 4, 2)` for inputs broadcastable to `(...)`."""
    x, y, heading, length, width = np.broadcast_arrays(*(np.asarray(a, float) for a in (x, y, heading, length, width)))
    c, s = np.cos(heading), np.sin(heading)
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], float)
    dl = signs[:, 0] * (length[..., None] / 2)
    dw = signs[:, 1] * (width[..., None] / 2)
    cx = x[..., None] + dl * c[..., None] - dw * s[..., None]
    cy = y[..., None] + dl * s[..., None] + dw * c[..., None]
    return np.stack([cx, cy], axis=-1)


def boxes_overlap(corners_a: np.ndarray, corners_b: np.ndarray) -> np.ndarray:
    """Separating-axis test for pairs of convex quadrilaterals.

    Args:
      corners_a, corners_b: `(..., 4, 2)` corners of boxes, broadcastable.
    Returns:
      `(...)` boolean, True where the two boxes intersect with positive area.
    """
    corners_a, corners_b = np.broadcast_arrays(corners_a, corners_b)
    overlap = np.ones(corners_a.shape[:-2], bool)
    for corners in (corners_a, corners_b):
        for k in range(2):  # two distinct edge directions per rectangle
            edge = corners[..., k + 1, :] - corners[..., k, :]
            axis = np.stack([-edge[..., 1], edge[..., 0]], axis=-1)
            pa = np.einsum("...ij,...j->...i", corners_a, axis)
            pb = np.einsum("...ij,...j->...i", corners_b, axis)
            overlap &= (pa.max(-1) > pb.min(-1)) & (pb.max(-1) > pa.min(-1))
    return overlap
