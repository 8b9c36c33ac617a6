"""A small closed-loop traffic simulator: agents follow fixed paths with an IDM law.

Shared by the synthetic scene generator (one batch: the logged world) and the
rule-based baseline policy (one batch entry per rollout). Every agent moves
along its own path (a polyline sampled every `ds` metres); its longitudinal
acceleration follows the intelligent driver model (Treiber et al., 2000) with
respect to the nearest obstacle on its path ahead: another agent whose box
touches the path, or a stop line whose signal is red (or yellow, when the
agent can still stop comfortably).

Shapes: B batch entries (rollouts), A agents, S path samples, T steps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from wosac_eval.sim import geometry as geo
from wosac_eval.sim.signals import CAUTION_STATES, STOP_STATES

ALWAYS_RED = -2  # stop-line signal index of a stop that never turns green (e.g. parking off the road)
NO_SIGNAL = -1

LOOKAHEAD_SPACING_M = 2.0
LOOKAHEAD_POINTS = 26  # 50 m of path ahead of the nose
MAX_BRAKE = 8.0
PREDICTION_S = 1.5  # how far ahead drivers anticipate crossing traffic
WINDOW = 12  # lookahead points tested per candidate obstacle (24 m of path)
LATERAL_ACCELERATION = 2.5  # m/s^2 drivers accept in turns
NEIGHBOURS = (
    10  # agents tested as obstacles for each agent, nearest first  # m/s^2, physical limit of an emergency stop
)


@dataclass
class Paths:
    """Agent paths, sampled every `ds` metres.

    xy: (B, A, S, 2) points; tangent: (B, A, S, 2) unit tangents.
    """

    xy: np.ndarray
    tangent: np.ndarray
    ds: float

    @classmethod
    def from_polylines(
        cls, polylines: list[list[np.ndarray]], ds: float, min_length: float, smooth_m: float = 0.0
    ) -> Paths:
        """Resamples nested lists [batch][agent] of polylines to one array, extending each
        straight past its end so that all have the same number of samples covering `min_length`.

        `smooth_m` averages the tangents over that length, so that noisy map polylines
        (real WOMD lanes) and kinks where lanes join do not make headings jitter."""
        num_s = int(np.ceil(min_length / ds)) + 1
        b, a = len(polylines), len(polylines[0])
        xy = np.zeros((b, a, num_s, 2))
        done: dict[int, np.ndarray] = {}  # rollouts often share a path object: resample it once
        for i, row in enumerate(polylines):
            for j, poly in enumerate(row):
                if id(poly) not in done:
                    done[id(poly)] = extend_resample(poly, ds, num_s)
                xy[i, j] = done[id(poly)]
        tangent = np.gradient(xy, axis=2)
        tangent /= np.maximum(np.linalg.norm(tangent, axis=-1, keepdims=True), 1e-9)
        half = int(round(smooth_m / ds / 2))
        if half > 0:
            padded = np.concatenate(
                [np.repeat(tangent[:, :, :1], half, 2), tangent, np.repeat(tangent[:, :, -1:], half, 2)], 2
            )
            cumulative = np.concatenate([np.zeros_like(padded[:, :, :1]), np.cumsum(padded, axis=2)], 2)
            tangent = cumulative[:, :, 2 * half + 1 :] - cumulative[:, :, : -2 * half - 1]
            tangent /= np.maximum(np.linalg.norm(tangent, axis=-1, keepdims=True), 1e-9)
        return cls(xy, tangent, ds)

    def curvature(self) -> np.ndarray:
        """(B, A, S) absolute curvature (1/m), averaged over ~4 m so that map noise does not spike it."""
        if getattr(self, "_curvature", None) is None:
            angle = np.unwrap(np.arctan2(self.tangent[..., 1], self.tangent[..., 0]), axis=-1)
            window = max(1, int(round(2.0 / self.ds)))
            padded = np.concatenate(
                [np.repeat(angle[..., :1], window, -1), angle, np.repeat(angle[..., -1:], window, -1)], -1
            )
            self._curvature = np.abs(padded[..., 2 * window :] - padded[..., : -2 * window]) / (2 * window * self.ds)
        return self._curvature

    def nearest(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Like `at` but at the nearest sample (no interpolation): cheaper, for lookahead points."""
        b, a, num_s = self.xy.shape[:3]
        if getattr(self, "_flat_nearest", None) is None:
            heading = np.arctan2(self.tangent[..., 1], self.tangent[..., 0])
            self._flat_nearest = np.concatenate([self.xy, heading[..., None]], axis=-1).reshape(-1, 3)
        index = np.clip(np.rint(s / self.ds).astype(np.int64), 0, num_s - 1)
        base = (np.arange(b * a) * num_s).reshape((b, a) + (1,) * (s.ndim - 2))
        v = self._flat_nearest[index + base]
        return v[..., :2], v[..., 2]

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (B, A, ..., 2) and headings (B, A, ...) at arc lengths `s` of shape (B, A, ...)."""
        b, a, num_s = self.xy.shape[:3]
        base = (np.arange(b * a) * num_s).reshape((b, a) + (1,) * (s.ndim - 2))
        return self._interpolate(base, s)

    def at_pairs(self, batch: np.ndarray, agent: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Like `at` for selected paths: batch, agent (C,) and arc lengths s (C, K)."""
        a, num_s = self.xy.shape[1:3]
        return self._interpolate(((batch * a + agent) * num_s)[:, None], s)

    def _interpolate(self, base: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear interpolation along the flattened paths; `base` is each path's first sample index."""
        num_s = self.xy.shape[2]
        if getattr(self, "_flat", None) is None:
            self._flat = np.concatenate([self.xy, self.tangent], axis=-1).reshape(-1, 4)
        f = np.clip(s / self.ds, 0.0, num_s - 1.000001)
        i0 = np.floor(f).astype(np.int64)
        w = (f - i0)[..., None]
        lo = self._flat[i0 + base]
        hi = self._flat[i0 + base + 1]
        v = lo + w * (hi - lo)
        return v[..., :2], np.arctan2(v[..., 3], v[..., 2])


def extend_resample(poly: np.ndarray, ds: float, num_s: int) -> np.ndarray:
    """Resamples `poly` every `ds` metres to exactly `num_s` points, extending straight."""
    poly = np.asarray(poly, float)[:, :2]
    keep = np.concatenate([[True], np.linalg.norm(np.diff(poly, axis=0), axis=1) > 1e-6])
    poly = poly[keep]
    if len(poly) < 2:
        raise ValueError("a path needs two distinct points")
    s = geo.arc_lengths(poly)
    targets = np.arange(num_s) * ds
    out = np.stack([np.interp(targets, s, poly[:, 0]), np.interp(targets, s, poly[:, 1])], axis=1)
    beyond = targets > s[-1]
    if beyond.any():
        direction = poly[-1] - poly[-2]
        direction /= np.linalg.norm(direction)
        out[beyond] = poly[-1] + (targets[beyond] - s[-1])[:, None] * direction
    return out


@dataclass
class Drivers:
    """Per-agent parameters, each of shape (B, A) unless noted.

    v0: (B, A, T) desired speed over time (m/s).
    moving: agents that move at all (parked cars do not).
    blind: (B, A, A) True where agent i ignores agent j (used to script a collision).
    crash_pairs: (B, A, A) pairs whose contact stops both (a scripted collision).
    """

    length: np.ndarray
    width: np.ndarray
    v0: np.ndarray
    a_max: np.ndarray
    b_comf: np.ndarray
    headway: np.ndarray
    s0: np.ndarray
    margin: np.ndarray
    max_brake: np.ndarray
    moving: np.ndarray
    ignore_signals: np.ndarray
    blind: np.ndarray
    crash_pairs: np.ndarray


@dataclass
class StopLines:
    """The stop lines on each agent's path, and the signals that control them.

    s: (B, A, K) arc lengths of the stop lines on each path (nan: none).
    signal: (B, A, K) the column of `states` that controls each stop line, or ALWAYS_RED / NO_SIGNAL.
    states: (T, G) TrafficSignalLaneState.State values of each signal group G at each step.
    """

    s: np.ndarray
    signal: np.ndarray
    states: np.ndarray

    @classmethod
    def of(cls, stops: Sequence[Sequence[Sequence[tuple[float, int]]]], states: np.ndarray) -> StopLines:
        """From each batch entry's agents' stops, (arc length, signal column) each, in path order."""
        shape = (len(stops), len(stops[0]) if stops else 0)
        k = max(1, max((len(agent) for entry in stops for agent in entry), default=0))
        s = np.full((*shape, k), np.nan)
        signal = np.full((*shape, k), NO_SIGNAL, np.int64)
        for b, entry in enumerate(stops):
            for i, agent in enumerate(entry):
                for j, (arc_length, column) in enumerate(agent):
                    s[b, i, j], signal[b, i, j] = arc_length, column
        return cls(s, signal, states)


@dataclass
class Rollout:
    """Simulated states, each (B, A, T)."""

    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    s: np.ndarray


def simulate(
    paths: Paths,
    drivers: Drivers,
    s_init: np.ndarray,
    v_init: np.ndarray,
    stop_lines: StopLines,
    num_steps: int,
    dt: float = 0.1,
) -> Rollout:
    """Runs the closed loop for `num_steps` states (the first is the initial state).

    Args:
      s_init, v_init: (B, A) initial arc length along the path and speed.
      stop_lines: the stop lines on the paths and their signals' states over the num_steps steps.
    """
    stop_s, stop_signal = stop_lines.s, stop_lines.signal
    b, a = s_init.shape
    s = s_init.astype(float).copy()
    v = v_init.astype(float).copy()
    crashed = np.zeros((b, a), bool)
    out_s = np.zeros((b, a, num_steps))
    out_v = np.zeros((b, a, num_steps))
    not_self = ~np.eye(a, dtype=bool)[None]
    k = np.arange(LOOKAHEAD_POINTS) * LOOKAHEAD_SPACING_M
    signal_states = np.asarray(stop_lines.states).reshape(num_steps, -1)
    for t in range(num_steps):
        out_s[..., t], out_v[..., t] = s, v
        if t == num_steps - 1:
            break
        xy, heading = paths.at(s)
        gap, lead_speed = _agent_gaps(paths, s, v, xy, heading, drivers, k)  # (B, i, j)
        seen = np.isfinite(gap) & not_self & ~drivers.blind
        # Two agents that each see the other on their path: the one nearer to the
        # conflict goes first, the other yields (avoids a standoff).
        mutual = seen & np.swapaxes(seen, 1, 2)
        gap_t = np.swapaxes(gap, 1, 2)
        index = np.arange(a)
        first_goes = (gap < gap_t) | ((gap == gap_t) & (index[None, :, None] < index[None, None, :]))
        seen &= ~(mutual & first_goes)
        gap = np.where(seen, gap, np.inf)
        lead = np.argmin(gap, axis=-1)
        lead_gap = np.take_along_axis(gap, lead[..., None], axis=-1)[..., 0]
        lead_v = np.take_along_axis(lead_speed, lead[..., None], axis=-1)[..., 0]
        # Stop lines.
        nose = s + drivers.length / 2
        stop_gap = stop_s - nose[..., None]
        column = np.clip(stop_signal, 0, None)
        state = signal_states[t][column] if signal_states.size else np.zeros_like(column)
        # Yellow: stop only when it is comfortable. Red: stop unless it would take an
        # emergency stop (a driver committed on yellow carries on over the line).
        can_stop = stop_gap > v[..., None] ** 2 / (2 * drivers.b_comf[..., None])
        can_brake = stop_gap > v[..., None] ** 2 / (2 * 0.6 * drivers.max_brake[..., None])
        red = (stop_signal == ALWAYS_RED) | ((stop_signal >= 0) & np.isin(state, STOP_STATES) & can_brake)
        yellow = (stop_signal >= 0) & np.isin(state, CAUTION_STATES) & can_stop
        holding = (red | yellow) & (stop_gap > -0.5) & ~drivers.ignore_signals[..., None]
        line_gap = np.where(holding & np.isfinite(stop_s), stop_gap + drivers.s0[..., None] - 1.0, np.inf).min(
            axis=-1, initial=np.inf
        )
        use_line = line_gap < lead_gap
        lead_gap = np.where(use_line, line_gap, lead_gap)
        lead_v = np.where(use_line, 0.0, lead_v)
        v0 = np.minimum(drivers.v0[..., t], _turn_speed(paths, s, drivers, k))
        acc = idm(v, v0, lead_gap, lead_v, drivers)
        acc = np.where(drivers.moving & ~crashed, acc, 0.0)
        v_new = np.where(drivers.moving & ~crashed, np.maximum(v + acc * dt, 0.0), 0.0 * v)
        s = s + 0.5 * (v + v_new) * dt
        v = v_new
        if drivers.crash_pairs.any():
            crashed |= _contacts(paths, s, drivers)
    x_y, hdg = paths.at(out_s)
    return Rollout(x_y[..., 0], x_y[..., 1], hdg, out_v, out_s)


def _agent_gaps(
    paths: Paths, s: Any, v: np.ndarray, xy: np.ndarray, heading: np.ndarray, d: Drivers, k: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Gap along each agent's path to every other agent that touches it, and that agent's speed along it.

    Agents crossing the path are also tested where they will be in PREDICTION_S
    seconds (constant velocity), so that drivers yield to crossing traffic before it
    is in front of them rather than braking hard when it arrives.
    Returns:
      gap: (B, i, j) metres from i's nose to j (inf where j is not on i's path ahead).
      speed: (B, i, j) j's speed projected on i's path (>= 0; 0 for a predicted conflict).
    """
    b, a = s.shape
    if a < 2:
        return np.full((b, a, a), np.inf), np.zeros((b, a, a))
    ahead_all = s[..., None] + d.length[..., None] / 2 + k  # (B, A, K)
    pts_all, pts_heading_all = paths.nearest(ahead_all)
    gap_now, along_now = _touching(pts_all, pts_heading_all, xy, xy, heading, d, k, d.moving[..., None])
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=-1)
    predicted = xy + (v * PREDICTION_S)[..., None] * direction
    # 30 to 150 degrees apart, and j actually moving.
    crossing = (np.abs(np.sin(heading[:, None, :] - heading[:, :, None])) > 0.5) & (v > 0.5)[:, None, :]
    gap_pred, _ = _touching(pts_all, pts_heading_all, xy, predicted, heading, d, k, crossing & d.moving[..., None])
    soon = gap_pred < (v * (PREDICTION_S + 1.0) + 3.0)[..., None]  # i gets there about when j does
    use_pred = soon & (gap_pred < gap_now)
    gap = np.where(use_pred, gap_pred, gap_now)
    speed = np.where(use_pred, 0.0, np.maximum(v[:, None, :] * along_now, 0.0))
    return gap, speed


def _touching(
    pts_all: Any,
    pts_heading_all: Any,
    xy: np.ndarray,
    xy_j: Any,
    heading: np.ndarray,
    d: Drivers,
    k: np.ndarray,
    pairs: np.ndarray,
) -> Any:
    """Gaps (B, i, j) from each agent's nose along its lookahead points to agents placed at
    `xy_j` (B, A, 2), and the cosine between j's heading and the path where it touches;
    only for the (i, j) where `pairs` (broadcastable to (B, i, j)) is True.

    A cheap test in each agent's heading frame first keeps only the pairs that can
    touch the path within the lookahead; the exact test runs on those pairs alone.
    """
    b, a = xy.shape[:2]
    gap_full = np.full((b, a, a), np.inf)
    along_full = np.zeros((b, a, a))
    ch, sh = np.cos(heading)[..., None], np.sin(heading)[..., None]
    px, py = pts_all[..., 0] - xy[..., 0][..., None], pts_all[..., 1] - xy[..., 1][..., None]
    path_lat = np.abs(-px * sh + py * ch).max(axis=-1)  # (B, A) how far the path strays from the heading line
    rx = xy_j[:, None, :, 0] - xy[:, :, None, 0]  # (B, i, j)
    ry = xy_j[:, None, :, 1] - xy[:, :, None, 1]
    lon = rx * ch + ry * sh
    lat = -rx * sh + ry * ch
    radius_j = 0.5 * np.hypot(d.length, d.width)[:, None, :]  # (B, 1, j)
    horizon = (k[-1] + d.length / 2)[..., None] + radius_j + 1.0
    side = (path_lat + d.width / 2 + d.margin)[..., None] + radius_j + 1.0
    near = (lon > -radius_j - 1.0) & (lon < horizon) & (np.abs(lat) < side) & pairs
    near[:, np.arange(a), np.arange(a)] = False
    cand_b, cand_i, cand_j = np.nonzero(near)
    if len(cand_b) == 0:
        return gap_full, along_full
    # Only a window of lookahead points around where j lies along the path can touch it.
    start = np.floor(
        (lon[cand_b, cand_i, cand_j] - d.length[cand_b, cand_i] / 2 - radius_j[cand_b, 0, cand_j] - 2.0)
        / LOOKAHEAD_SPACING_M
    ).astype(np.int64)
    window = np.clip(start, 0, len(k) - WINDOW)[:, None] + np.arange(WINDOW)  # (C, W)
    pts = pts_all[cand_b[:, None], cand_i[:, None], window]  # (C, W, 2)
    pts_heading = pts_heading_all[cand_b[:, None], cand_i[:, None], window]
    k = k[window]
    dx = xy_j[cand_b, cand_j, 0][:, None] - pts[..., 0]
    dy = xy_j[cand_b, cand_j, 1][:, None] - pts[..., 1]
    dist = np.sqrt(dx * dx + dy * dy)
    hj = heading[cand_b, cand_j][:, None]
    cos_signed = np.cos(hj - pts_heading)
    cos_d = np.abs(cos_signed)
    sin_d = np.sqrt(np.maximum(1.0 - cos_d * cos_d, 0.0))
    len_j = d.length[cand_b, cand_j][:, None] / 2
    wid_j = d.width[cand_b, cand_j][:, None] / 2
    reach = (d.width[cand_b, cand_i] / 2 + d.margin[cand_b, cand_i])[:, None] + len_j * sin_d + wid_j * cos_d
    gap_k = np.where(dist < reach, (k - LOOKAHEAD_SPACING_M / 2) - (len_j * cos_d + wid_j * sin_d), np.inf)  # (C, W)
    first = np.argmin(gap_k, axis=-1)
    rows = np.arange(len(first))
    gap_full[cand_b, cand_i, cand_j] = gap_k[rows, first]
    along_full[cand_b, cand_i, cand_j] = cos_signed[rows, first]
    return gap_full, along_full


def _turn_speed(paths: Paths, s: np.ndarray, d: Drivers, k: np.ndarray) -> np.ndarray:
    """(B, A) highest speed from which each agent can slow (comfortably) to take the bends ahead."""
    curvature = paths.curvature()
    num_s = curvature.shape[2]
    ahead = s[..., None] + k  # from the centre: the current bend counts too
    index = np.clip(np.round(ahead / paths.ds).astype(np.int64), 0, num_s - 1)
    kappa = np.take_along_axis(curvature, index, axis=2)
    v_bend = np.sqrt(LATERAL_ACCELERATION / np.maximum(kappa, 1e-6))
    return np.sqrt(v_bend**2 + 2.0 * d.b_comf[..., None] * k).min(axis=-1)


def idm(v: np.ndarray, v0: np.ndarray, gap: np.ndarray, lead_v: np.ndarray, d: Drivers) -> np.ndarray:
    """Intelligent-driver-model acceleration (B, A); free road when `gap` is inf."""
    v0 = np.maximum(v0, 0.1)
    free = np.where(v <= v0, d.a_max * (1.0 - (v / v0) ** 4), -d.b_comf * (1.0 - (v0 / np.maximum(v, 1e-3)) ** 2))
    s_star = d.s0 + np.maximum(0.0, v * d.headway + v * (v - lead_v) / (2.0 * np.sqrt(d.a_max * d.b_comf)))
    interaction = np.where(np.isfinite(gap), (s_star / np.maximum(gap, 0.1)) ** 2, 0.0)
    acc = free - d.a_max * interaction
    # Like the enhanced IDM (Kesting et al., 2010): when plain IDM over-reacts to a gap
    # that a calmer deceleration handles (an obstacle appearing at a moderate
    # distance), brake only somewhat harder than what stopping behind it needs.
    closing = np.maximum(v - lead_v, 0.0)
    needed = closing**2 / (2.0 * np.maximum(gap - 0.5 * d.s0, 0.1))
    calm = -np.maximum(1.3 * needed, d.b_comf)
    acc = np.where(np.isfinite(gap) & (gap > 0.5 * d.s0), np.maximum(acc, np.minimum(calm, free)), acc)
    return np.clip(acc, -d.max_brake, d.a_max)


def _contacts(paths: Paths, s: np.ndarray, d: Drivers) -> np.ndarray:
    """(B, A) agents whose box now overlaps a scripted crash partner."""
    xy, heading = paths.at(s)
    corners = geo.box_corners(xy[..., 0], xy[..., 1], heading, d.length, d.width)  # (B, A, 4, 2)
    overlap = geo.boxes_overlap(corners[:, :, None], corners[:, None, :]) & d.crash_pairs
    return overlap.any(axis=2) | overlap.any(axis=1)
