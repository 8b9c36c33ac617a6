"""Red-light violations: crossing a signal's stop point while it shows stop.

An object violates a red light at step t when, at that step, it is valid, its
nearest surface-street lane carries a signal in a stop state, and between t-1
and t it passed from behind to ahead of the signal's stop point, measured along
the lane segment nearest to that stop point.

The nearest-lane search reproduces the official measure exactly, including its
quirks: the "distance" to a segment is |p + t d| (p from the segment start to
the point, d along the segment, t the clamped projection) rather than
|p - t d|, and each shorter lane keeps a segment from its last point to the
origin (the official padding), which counts as valid. That measure lies
at least |p|, so a k-d tree over segment starts finds all candidates.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterable
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from wosac_eval.arrays.scenario import TrafficSignals
from wosac_eval.features import ops
from wosac_eval.features.compiled import cached_loop, compiled
from wosac_eval.features.spatial import finite_rows, first_minimum, non_finite_pick, pad_polylines, tree_candidates
from wosac_eval.features.xp import array_namespace, divide, errstate, sqrt

_F = np.float32
LANE_STATE_STOP_VALUES = (1, 4)  # LANE_STATE_ARROW_STOP, LANE_STATE_STOP


@dataclasses.dataclass(frozen=True)
class LaneTable:
    """Lane segments in the official padded (lane, segment) order.

    Attributes:
      points: float32 `(num_lanes, max_points, 2)`, zero padded.
      start, delta: float32 `(num_lanes * (max_points - 1), 2)`.
      valid: bool, segments whose start point is a real point.
      lane_ids: int64 `(num_lanes,)`.
      tree_segment: int64, the valid segments, in the order of `tree`'s points.
    """

    points: np.ndarray
    start: np.ndarray
    delta: np.ndarray
    valid: np.ndarray
    lane_ids: np.ndarray
    num_segments: int
    tree_segment: np.ndarray

    @functools.cached_property
    def tree(self) -> cKDTree:
        """k-d tree over the valid segments' starts, built on first use: most
        scenarios never need a lane search (see `red_light_violation`)."""
        return cKDTree(self.start[self.tree_segment].astype(np.float64))


def signals_from(signals: TrafficSignals | None, start: int) -> TrafficSignals | None:
    """The signal states from step `start` on (None stays None)."""
    if signals is None:
        return None
    return dataclasses.replace(signals, state=signals.state[start:], stop_point=signals.stop_point[start:])


def build_lane_table(lanes: Iterable[np.ndarray], lane_ids: Iterable[int]) -> LaneTable | None:
    kept = [(np.asarray(p, _F)[:, :2], i) for p, i in zip(lanes, lane_ids) if len(p) >= 2]
    if not kept:
        return None
    max_points = max(len(p) for p, _ in kept)
    points, point_valid = pad_polylines([p for p, _ in kept], max_points)
    start = points[:, :-1].reshape(-1, 2)
    delta = (points[:, 1:] - points[:, :-1]).reshape(-1, 2)
    valid = point_valid[:, :-1].reshape(-1)
    tree_segment = np.flatnonzero(valid)
    return LaneTable(
        points=points,
        start=start,
        delta=delta,
        valid=valid,
        lane_ids=np.array([i for _, i in kept], np.int64),
        num_segments=max_points - 1,
        tree_segment=tree_segment,
    )


def lane_measure(xy: Any, start: Any, delta: Any) -> Any:
    """The official nearest-lane measure |p + clamp(t) d| in float32.

    Args:
      xy, start, delta: float32 `(..., 2)`, broadcast (numpy or JAX arrays).
    Returns:
      float32 `(...)`.
    """
    xp = array_namespace(xy, start, delta)
    px = xy[..., 0] - start[..., 0]
    py = xy[..., 1] - start[..., 1]
    along = px * delta[..., 0] + py * delta[..., 1]
    squared = delta[..., 0] * delta[..., 0] + delta[..., 1] * delta[..., 1]
    with errstate(xp, divide="ignore", invalid="ignore"):
        t = xp.clip(xp.where(squared == 0, _F(0), divide(along, squared)), _F(0), _F(1))
    mx = px + delta[..., 0] * t
    my = py + delta[..., 1] * t
    return sqrt(mx * mx + my * my, xp)


def nearest_lane_segment(table: LaneTable, xy: np.ndarray) -> np.ndarray:
    """Flat (lane * num_segments + segment) index of the nearest segment.

    Args:
      xy: float32 `(num_points, 2)`.
    Returns:
      int64 `(num_points,)`.
    """
    q = np.asarray(xy, np.float64)
    finite = finite_rows(q)
    if not finite.all():
        out = np.full(len(q), non_finite_pick(table.valid), np.int64)
        if finite.any():
            out[finite] = nearest_lane_segment(table, np.asarray(xy)[finite])
        return out
    xy32 = np.asarray(xy, _F)

    def measure(rows: Any, points: Any) -> Any:
        seg = table.tree_segment[points]
        return lane_measure(xy32[rows], table.start[seg], table.delta[seg])

    # The measure is at least the distance to the segment start, so segments
    # whose start is farther than the best measure found cannot win.
    qi, si = tree_candidates(table.tree, q, lambda best: best * (1 + 1e-5) + 1e-3, measure)
    si = table.tree_segment[si]
    d = lane_measure(np.asarray(xy, _F)[qi], table.start[si], table.delta[si])
    rows, best = first_minimum(qi, d, si)
    out = np.empty(len(q), np.int64)
    out[rows] = si[best]
    return out


def stop_point_segments(table: LaneTable, signals: TrafficSignals) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each (step, signal): the lane segment nearest the stop point.

    Returns (segment_start, segment_delta, lane_known), float32 `(num_steps, num_signals, 2)`
    twice and bool `(num_steps, num_signals)`.
    """
    match = table.lane_ids[None, :] == signals.lane_id[:, None]  # (signals, lanes)
    lane_known = match.any(axis=1)
    lane_index = np.argmax(match, axis=1)
    pts = table.points[lane_index]  # (signals, P, 2)
    seg_valid = np.zeros(pts.shape[:2], bool)
    seg_valid[:, :-1] = table.valid.reshape(len(table.lane_ids), -1)[lane_index]
    start, delta = pts[:, :-1], pts[:, 1:] - pts[:, :-1]  # (signals, S, 2)
    stop = np.ascontiguousarray(signals.stop_point, _F)  # (num_steps, num_signals, 2)
    # A signal's stop point rarely moves: it is measured where it differs from the step before (told apart
    # by its bits), and each step takes the measure of its signal's last change: every step's values.
    bits = stop.view(np.int64)[..., 0]  # (num_steps, num_signals)
    changed = np.ones(bits.shape, bool)
    changed[1:] = bits[1:] != bits[:-1]
    step_at, signal_at = np.nonzero(changed)
    d = lane_measure(stop[step_at, signal_at][:, None, :], start[signal_at], delta[signal_at])
    d = np.where(seg_valid[signal_at, :-1], d, _F(1e10))
    seg_at_change = np.zeros(bits.shape, np.int64)
    seg_at_change[step_at, signal_at] = np.argmin(d, axis=-1)
    last_change = np.maximum.accumulate(np.where(changed, np.arange(len(bits))[:, None], 0), axis=0)
    seg = seg_at_change[last_change, np.arange(bits.shape[1])[None, :]]  # (num_steps, num_signals)
    sig = np.arange(len(signals.lane_id))[None, :]
    seg_start = pts[sig, seg]
    seg_delta = pts[sig, seg + 1] - seg_start
    return seg_start, seg_delta, np.broadcast_to(lane_known, seg.shape)


def line_parameter(px: Any, py: Any, sx: Any, sy: Any, dx: Any, dy: Any, squared: Any) -> Any:
    """Where a point projects on a segment's line, in segment lengths (0 on a segment of no length).

    An elementwise `ops` kernel: `squared` is dx * dx + dy * dy; all float32 `(...)`.
    """
    along = (px - sx) * dx
    along = along + (py - sy) * dy
    return ops.where(squared == _F(0), _F(0), ops.divide(along, squared))


def _stop_lines(seg_start: Any, seg_delta: Any, stop_point: Any, xp: Any) -> Any:
    """The stop lines' segments and where the stop points lie on them: (sx, sy, dx, dy, squared,
    stop_t), float32 `(num_steps, num_signals)` each (`stop_line_crossings`)."""
    sx, sy, dx, dy = seg_start[..., 0], seg_start[..., 1], seg_delta[..., 0], seg_delta[..., 1]
    squared = dx * dx + dy * dy
    with errstate(xp, divide="ignore", invalid="ignore"):
        stop_t = line_parameter(stop_point[..., 0], stop_point[..., 1], sx, sy, dx, dy, squared)
    return sx, sy, dx, dy, squared, stop_t


def stop_line_crossings(xy: Any, valid: Any, seg_start: Any, seg_delta: Any, stop_point: Any, stopping: Any) -> Any:
    """Crossings of stopped signals' lines: every red-light condition but the object's lane.

    The lane search runs only where this is true, which is rare. (numpy and JAX arrays; numpy's
    `red_light_violation` runs the same kernel in a compiled loop, `_crossings`.)

    Args:
      xy: float32 `(..., num_objects, num_steps, 2)`.
      valid: bool `(..., num_objects, num_steps)`.
      seg_start, seg_delta: float32 `(num_steps, num_signals, 2)`, the lane
        segment nearest each stop point.
      stop_point: float32 `(num_steps, num_signals, 2)`.
      stopping: bool `(num_steps, num_signals)`, the signal shows stop and its lane is known.
    Returns:
      bool `(..., num_objects, num_steps, num_signals)`.
    """
    xp = array_namespace(xy, valid, seg_start)
    sx, sy, dx, dy, squared, stop_t = _stop_lines(seg_start, seg_delta, stop_point, xp)
    with errstate(xp, divide="ignore", invalid="ignore"):
        # Coordinates one at a time: (..., O, T, S) arrays, no trailing axis of two.
        obj_t = line_parameter(xy[..., 0, None], xy[..., 1, None], sx, sy, dx, dy, squared)
    behind = obj_t < stop_t
    ahead = obj_t > stop_t
    no_step = xp.zeros(behind.shape[:-2] + (1,) + behind.shape[-1:], dtype=bool)
    crossed = xp.concatenate([no_step, behind[..., :-1, :] & ahead[..., 1:, :]], axis=-2)
    return valid[..., None] & stopping & crossed


_line_parameter = compiled(line_parameter, True)


@cached_loop
def _crossings(
    x: Any, y: Any, valid: Any, sx: Any, sy: Any, dx: Any, dy: Any, squared: Any, stop_t: Any, stopping: Any
) -> Any:
    """`stop_line_crossings` of x, y, valid `(batch, num_objects, num_steps)` and the signals' segments
    (sx, sy, dx, dy, squared, stop_t, stopping: `(num_steps, num_signals)`), compiled, each line
    parameter computed once; also whether each box crossed any line, `(batch, num_objects, num_steps)`."""
    batch, num_objects, num_steps = x.shape
    num_signals = sx.shape[1]
    out = np.zeros((batch, num_objects, num_steps, num_signals), np.bool_)
    crossed_any = np.zeros((batch, num_objects, num_steps), np.bool_)
    behind = np.zeros(num_signals, np.bool_)  # at the step before
    at = np.empty(num_signals, np.float32)
    for b in range(batch):
        for o in range(num_objects):
            for t in range(num_steps):
                px, py = x[b, o, t], y[b, o, t]
                for s in range(num_signals):  # branch-free: the compiler vectorises it
                    at[s] = _line_parameter(px, py, sx[t, s], sy[t, s], dx[t, s], dy[t, s], squared[t, s])
                for s in range(num_signals):
                    crossed = t > 0 and behind[s] and at[s] > stop_t[t, s] and stopping[t, s] and valid[b, o, t]
                    out[b, o, t, s] = crossed
                    crossed_any[b, o, t] |= crossed
                    behind[s] = at[s] < stop_t[t, s]
    return out, crossed_any


def compiled_stop_line_crossings(
    x: np.ndarray,
    y: np.ndarray,
    valid: np.ndarray,
    seg_start: np.ndarray,
    seg_delta: np.ndarray,
    stop_point: np.ndarray,
    stopping: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """`stop_line_crossings` by `_crossings`: x, y float32 and valid `(..., num_objects, num_steps)`; and
    whether each box crossed any line, bool `(..., num_objects, num_steps)`."""
    lines = [np.ascontiguousarray(a, _F) for a in _stop_lines(seg_start, seg_delta, stop_point, np)]
    flat = lambda a, dtype: np.ascontiguousarray(np.reshape(a, (-1,) + np.shape(a)[-2:]), dtype)  # noqa: E731
    out, crossed_any = _crossings(
        flat(x, _F), flat(y, _F), flat(valid, bool), *lines, np.ascontiguousarray(stopping, bool)
    )
    return out.reshape(np.shape(valid) + (lines[0].shape[1],)), crossed_any.reshape(np.shape(valid))


def red_light_violation(
    x: np.ndarray, y: np.ndarray, valid: np.ndarray, lanes: LaneTable | None, signals: TrafficSignals | None
) -> np.ndarray:
    """Per-step red-light violations of the given objects.

    Args:
      x, y: float32 `(..., num_objects, num_steps)`.
      valid: bool `(..., num_objects, num_steps)`.
      lanes: surface-street lanes, or None when the scenario has none.
      signals: per-step signal states, `num_steps` long, or None.
    Returns:
      bool `(..., num_objects, num_steps)`; all False without lanes or signals.
    """
    if lanes is None or signals is None:
        return np.zeros(np.shape(valid), bool)
    num_steps = x.shape[-1]
    if signals.state.shape[0] != num_steps:
        raise ValueError(
            f"the scenario has {signals.state.shape[0]} dynamic map states, expected one per step ({num_steps})"
        )
    # Only signals that show a stop at some step and sit on a known lane can be violated.
    is_stop = np.isin(signals.state, LANE_STATE_STOP_VALUES)  # (T, S)
    relevant = is_stop.any(axis=0) & np.isin(signals.lane_id, lanes.lane_ids)
    if not relevant.any():
        return np.zeros(np.shape(valid), bool)
    signals = dataclasses.replace(
        signals,
        lane_id=signals.lane_id[relevant],
        state=signals.state[:, relevant],
        stop_point=signals.stop_point[:, relevant],
    )
    seg_start, seg_delta, _ = stop_point_segments(lanes, signals)  # (T, S, 2); every kept lane is known
    suspect, crossed_any = compiled_stop_line_crossings(
        x, y, valid, seg_start, seg_delta, signals.stop_point, is_stop[:, relevant]
    )
    violation = np.zeros(valid.shape, dtype=bool)
    where = np.nonzero(crossed_any)
    if where[0].size:
        points = np.stack([x[where], y[where]], axis=-1).astype(_F)
        lane_row = nearest_lane_segment(lanes, points) // lanes.num_segments
        on_lane = lanes.lane_ids[lane_row][:, None] == signals.lane_id  # (points, S)
        violation[where] = np.any(suspect[where] & on_lane, axis=-1)
    return violation
