"""Baseline sim-agent policies that work on any `Scenario` (synthetic or real WOMD).

Each policy maps a `SimContext` (what a policy may see: the first 11 steps of
every track, the map, traffic signals) to simulated futures of every sim agent,
an array of shape `(num_rollouts, num_objects, 80, 4)` holding
center_x, center_y, center_z, heading for steps 11..90.

* ``constant_velocity``: every agent keeps its current velocity and heading
  (all rollouts identical).
* ``log_replay_noise``: the logged future plus smooth random perturbations that
  grow with time; it peeks at the future, so it is an upper reference, not a
  valid method, and needs the logged future (validation-style scenarios).
* ``idm``: a closed-loop rule-based policy. Vehicles and cyclists follow lanes
  (choosing exits at random per rollout) with an intelligent-driver-model
  car-following law that stops at red lights; other agents move straight ahead
  at their current speed but also brake for obstacles. Rollouts differ by
  desired speeds, time headways and route choices.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.object_types import TYPE_CYCLIST, TYPE_PEDESTRIAN
from wosac_eval.challenges import CURRENT_TIME_INDEX, NUM_ROLLOUTS, STEP_SECONDS
from wosac_eval.sim import engine
from wosac_eval.sim import geometry as geo

if TYPE_CHECKING:  # the policies read a scenario's fields; they need no import of its class
    from wosac_eval.protos import scenario_pb2

# The challenge's timing, from the one place that defines it.
CURRENT = CURRENT_TIME_INDEX
NUM_FUTURE = challenges.spec("sim_agents").num_simulation_steps
DT = STEP_SECONDS
MPH = 0.44704


@dataclass
class Lane:
    id: int
    polyline: np.ndarray  # (num_points, 2)
    exits: list[int]
    speed_limit: float  # m/s, 0 when unknown


@dataclass
class SimContext:
    """What a policy sees of one scenario. Arrays over sim agents (N) and history steps (11).

    x, y, z, heading, valid: (N, 11); length, width, height: (N,); velocity: (N, 2) at the current step.
    log_future: (N, 80, 4) x, y, z, heading (nan where the log is invalid or absent).
    signals: (91, G) states of the G signal-controlled lanes `signal_lanes`; steps the
      scenario does not cover hold the last known state.
    """

    scenario_id: str
    object_ids: np.ndarray
    object_type: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    heading: np.ndarray
    valid: np.ndarray
    length: np.ndarray
    width: np.ndarray
    height: np.ndarray
    velocity: np.ndarray
    log_future: np.ndarray
    lanes: dict[int, Lane]
    signal_lanes: list[int]
    signal_stop_points: np.ndarray  # (G, 2)
    signals: np.ndarray

    @property
    def num_agents(self) -> int:
        return len(self.object_ids)


def context_from_scenario(scenario: scenario_pb2.Scenario) -> SimContext:
    """Extracts the sim agents (tracks valid at step 10) and the map of a `Scenario` proto."""
    tracks = [t for t in scenario.tracks if len(t.states) > CURRENT and t.states[CURRENT].valid]
    n = len(tracks)
    hist = np.zeros((n, CURRENT + 1, 5))
    valid = np.zeros((n, CURRENT + 1), bool)
    future = np.full((n, NUM_FUTURE, 4), np.nan)
    for i, t in enumerate(tracks):
        for k, st in enumerate(t.states[: CURRENT + 1]):
            if st.valid:
                hist[i, k] = (st.center_x, st.center_y, st.center_z, st.heading, 0.0)
                valid[i, k] = True
        for k, st in enumerate(t.states[CURRENT + 1 : CURRENT + 1 + NUM_FUTURE]):
            if st.valid:
                future[i, k] = (st.center_x, st.center_y, st.center_z, st.heading)
    cur = [t.states[CURRENT] for t in tracks]
    lanes = {}
    for f in scenario.map_features:
        if f.HasField("lane") and len(f.lane.polyline) >= 2:
            poly = np.array([(p.x, p.y) for p in f.lane.polyline])
            lanes[f.id] = Lane(f.id, poly, list(f.lane.exit_lanes), f.lane.speed_limit_mph * MPH)
    signal_lanes = sorted({ls.lane for d in scenario.dynamic_map_states for ls in d.lane_states if ls.lane in lanes})
    column = {lid: c for c, lid in enumerate(signal_lanes)}
    steps = CURRENT + 1 + NUM_FUTURE
    signals = np.zeros((steps, len(signal_lanes)), np.int64)
    stop_points = np.full((len(signal_lanes), 2), np.nan)
    last = np.zeros(len(signal_lanes), np.int64)
    for t in range(steps):
        if t < len(scenario.dynamic_map_states):
            for ls in scenario.dynamic_map_states[t].lane_states:
                if ls.lane in column:
                    last[column[ls.lane]] = ls.state
                    stop_points[column[ls.lane]] = (ls.stop_point.x, ls.stop_point.y)
        signals[t] = last
    return SimContext(
        scenario_id=scenario.scenario_id,
        object_ids=np.array([t.id for t in tracks], np.int64),
        object_type=np.array([t.object_type for t in tracks], np.int64),
        x=hist[..., 0],
        y=hist[..., 1],
        z=hist[..., 2],
        heading=hist[..., 3],
        valid=valid,
        length=np.array([s.length for s in cur], float),
        width=np.array([s.width for s in cur], float),
        height=np.array([s.height for s in cur], float),
        velocity=np.array([(s.velocity_x, s.velocity_y) for s in cur], float).reshape(n, 2),
        log_future=future,
        lanes=lanes,
        signal_lanes=signal_lanes,
        signal_stop_points=stop_points,
        signals=signals,
    )


def _hold(ctx: SimContext, num_rollouts: int, x: np.ndarray, y: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Stacks (R, N, 80) x, y, heading with z held at its current value into (R, N, 80, 4)."""
    z = np.broadcast_to(ctx.z[:, CURRENT][None, :, None], x.shape)
    return np.stack([x, y, z, heading], axis=-1)


def constant_velocity(ctx: SimContext, rng: np.random.Generator, num_rollouts: int = NUM_ROLLOUTS) -> np.ndarray:
    """Straight-line extrapolation of the current velocity; heading held."""
    del rng  # deterministic: every rollout is the same
    t = np.arange(1, NUM_FUTURE + 1) * DT
    x = ctx.x[:, CURRENT, None] + ctx.velocity[:, 0, None] * t
    y = ctx.y[:, CURRENT, None] + ctx.velocity[:, 1, None] * t
    h = np.broadcast_to(ctx.heading[:, CURRENT, None], x.shape)
    rep = lambda a: np.broadcast_to(a[None], (num_rollouts,) + a.shape)  # noqa: E731
    return _hold(ctx, num_rollouts, rep(x), rep(y), rep(h)).copy()


def _filled_log(ctx: SimContext) -> np.ndarray:
    """Logged future with gaps filled: interpolated inside, constant velocity past the last valid step."""
    full = np.concatenate(
        [np.stack([ctx.x, ctx.y, ctx.z, ctx.heading], -1)[:, CURRENT : CURRENT + 1], ctx.log_future], axis=1
    )
    steps = np.arange(NUM_FUTURE + 1)
    out = full.copy()
    for i in range(ctx.num_agents):
        ok = ~np.isnan(full[i, :, 0])
        known = steps[ok]
        for c in range(4):
            values = full[i, ok, c] if c != 3 else np.unwrap(full[i, ok, 3])
            out[i, :, c] = np.interp(steps, known, values)
        last = known[-1]
        if last < NUM_FUTURE:  # the log ends early: carry on at the last observed velocity
            if len(known) >= 2:
                velocity = (full[i, last, :2] - full[i, known[-2], :2]) / ((last - known[-2]) * DT)
            else:
                velocity = ctx.velocity[i]
            ahead = (steps[last + 1 :] - last)[:, None] * DT
            out[i, last + 1 :, :2] = full[i, last, :2] + ahead * velocity
    out[..., 3] = geo.wrap_angle(out[..., 3])
    return out[:, 1:]


def log_replay_noise(
    ctx: SimContext, rng: np.random.Generator, num_rollouts: int = NUM_ROLLOUTS, noise_m: float = 0.5
) -> np.ndarray:
    """The logged future (gaps filled) plus smooth per-rollout noise of up to `noise_m` metres."""
    base = _filled_log(ctx)  # (N, 80, 4)
    t = np.arange(1, NUM_FUTURE + 1) * DT
    n = ctx.num_agents
    growth = t / t[-1]
    amp = rng.normal(0.0, noise_m, (num_rollouts, n, 2, 2))  # (R, N, axis, harmonic)
    freq = rng.uniform(0.05, 0.25, (num_rollouts, n, 2, 2))
    phase = rng.uniform(0, 2 * np.pi, (num_rollouts, n, 2, 2))
    wave = amp[..., None] * np.sin(2 * np.pi * freq[..., None] * t + phase[..., None])  # (R, N, 2, 2, 80)
    offset = wave.sum(axis=3) * growth  # (R, N, 2, 80)
    heading_noise = rng.normal(0.0, 0.02, (num_rollouts, n, 1)) * growth
    out = np.broadcast_to(base[None], (num_rollouts,) + base.shape).copy()
    out[..., 0] += offset[:, :, 0]
    out[..., 1] += offset[:, :, 1]
    out[..., 3] = geo.wrap_angle(out[..., 3] + heading_noise)
    return out


# ---------------------------------------------------------------------------------------------
# Rule-based closed-loop policy.

_LANE_MATCH_M = 3.0
_LANE_MATCH_RAD = np.deg2rad(50.0)
_BLEND_M = 15.0  # distance over which an agent merges onto its lane centre
_SMOOTH_M = 6.0  # heading smoothing along lanes (real lane polylines are noisy)


def _lane_segments(ctx: SimContext) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ids, starts, ends = [], [], []
    for lane in ctx.lanes.values():
        ids.append(np.full(len(lane.polyline) - 1, lane.id))
        starts.append(lane.polyline[:-1])
        ends.append(lane.polyline[1:])
    if not ids:
        return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2))
    return np.concatenate(ids), np.concatenate(starts), np.concatenate(ends)


def _match_lanes(ctx: SimContext) -> list[tuple[int, int, float] | None]:
    """For each agent: (lane id, segment index within the lane, signed lateral offset) or None."""
    seg_ids, a, b = _lane_segments(ctx)
    out: list[tuple[int, int, float] | None] = [None] * ctx.num_agents
    if len(seg_ids) == 0:
        return out
    first_index: dict[int, int] = {}
    for k, lid in enumerate(seg_ids):
        first_index.setdefault(int(lid), k)
    p = np.stack([ctx.x[:, CURRENT], ctx.y[:, CURRENT]], -1)
    ab = b - a
    seg_len2 = np.maximum((ab**2).sum(-1), 1e-9)
    rel = p[:, None, :] - a[None]
    tpar = np.clip((rel * ab[None]).sum(-1) / seg_len2, 0.0, 1.0)
    closest = a[None] + tpar[..., None] * ab[None]
    dist = np.linalg.norm(p[:, None, :] - closest, axis=-1)
    seg_heading = np.arctan2(ab[:, 1], ab[:, 0])
    dh = np.abs(geo.wrap_angle(ctx.heading[:, CURRENT, None] - seg_heading[None]))
    cost = dist + 4.0 * dh
    cost = np.where((dist < _LANE_MATCH_M) & (dh < _LANE_MATCH_RAD), cost, np.inf)
    best = np.argmin(cost, axis=1)
    for i in range(ctx.num_agents):
        k = best[i]
        if not np.isfinite(cost[i, k]) or ctx.object_type[i] not in (1, 3):
            continue
        lid = int(seg_ids[k])
        cross = ab[k, 0] * rel[i, k, 1] - ab[k, 1] * rel[i, k, 0]
        out[i] = (lid, int(k - first_index[lid]), float(np.sign(cross) * dist[i, k]))
    return out


def _route(
    ctx: SimContext, lane_id: int, seg: int, start: np.ndarray, rng: np.random.Generator, min_length: float
) -> Any:
    """Polyline from `start` along lane `lane_id` (from segment `seg`) and random successors,
    the (arc length, signal column) of the signal-controlled lanes it enters, and the lane ids taken."""
    column = {lid: c for c, lid in enumerate(ctx.signal_lanes)}
    lane = ctx.lanes[lane_id]
    pieces = [start[None], lane.polyline[seg + 1 :]]
    stops: list[tuple[float, int]] = []
    length = float(geo.arc_lengths(np.concatenate(pieces))[-1])
    current = lane
    visited = {lane_id}
    visited_order = [lane_id]
    while length < min_length and current.exits:
        options = [e for e in current.exits if e in ctx.lanes and e not in visited]
        if not options:
            break
        nxt = ctx.lanes[options[int(rng.integers(len(options)))]]
        visited.add(nxt.id)
        visited_order.append(nxt.id)
        if nxt.id in column:  # WOMD puts the stop point at the start of the controlled lane
            stops.append((length, column[nxt.id]))
        pieces.append(nxt.polyline[1:])
        length += float(geo.arc_lengths(nxt.polyline)[-1])
        current = nxt
    return np.concatenate(pieces), stops, tuple(visited_order)


def idm(ctx: SimContext, rng: np.random.Generator, num_rollouts: int = NUM_ROLLOUTS) -> np.ndarray:
    """Closed-loop lane following with IDM car following and red-light stops."""
    n, r = ctx.num_agents, num_rollouts
    if n == 0:
        return np.zeros((r, 0, NUM_FUTURE, 4))
    speed = np.linalg.norm(ctx.velocity, axis=-1)
    heading = ctx.heading[:, CURRENT]
    matches = _match_lanes(ctx)
    min_length = float(np.max(speed)) * NUM_FUTURE * DT * 1.5 + 80.0
    routes = _routes(ctx, rng, matches, r, min_length)
    paths = engine.Paths.from_polylines(routes.polylines, 1.0, min_length, smooth_m=_SMOOTH_M)
    drivers = _drivers(ctx, rng, routes.v0)
    along = np.maximum(np.einsum("nd,nd->n", ctx.velocity, np.stack([np.cos(heading), np.sin(heading)], -1)), 0.0)
    v_init = np.where(np.array([m is None for m in matches]), speed, along)
    stop_lines = engine.StopLines.of(routes.stops, ctx.signals[CURRENT:])
    out = engine.simulate(
        paths, drivers, np.zeros((r, n)), np.broadcast_to(v_init, (r, n)), stop_lines, NUM_FUTURE + 1, DT
    )
    # Merge from the current position onto the lane centre over _BLEND_M metres of travel.
    lateral = routes.lateral
    s = out.s[..., 1:]
    fade = np.exp(-s / _BLEND_M)
    off = lateral[None, :, None] * fade
    slope = -lateral[None, :, None] / _BLEND_M * fade
    h_path = out.heading[..., 1:] + np.arctan(slope)
    x = out.x[..., 1:] - np.sin(out.heading[..., 1:]) * off
    y = out.y[..., 1:] + np.cos(out.heading[..., 1:]) * off
    h0 = out.heading[..., 0] + np.arctan(-lateral[None] / _BLEND_M)
    dh = geo.wrap_angle(heading[None] - h0)[..., None] * fade
    return _hold(ctx, r, x, y, geo.wrap_angle(h_path + dh))


@dataclass
class _Routes:
    """Each rollout's path for each agent, and what the agent does on it.

    polylines, stops: [rollout][agent] the path, and its stop lines (arc length, signal column).
    lateral: `(num_objects,)` the agent's offset from its lane's centre (0 off the lanes).
    v0: `(num_rollouts, num_objects)` desired speed (0: parked).
    """

    polylines: list[list[np.ndarray]]
    stops: list[list[list]]
    lateral: np.ndarray
    v0: np.ndarray


def _routes(ctx: SimContext, rng: np.random.Generator, matches: list, r: int, min_length: float) -> _Routes:
    """Each agent's route in each of the `r` rollouts: on from its lane (a random turn at each junction),
    or straight ahead when it is on none; and its desired speed."""
    n = ctx.num_agents
    pos = np.stack([ctx.x[:, CURRENT], ctx.y[:, CURRENT]], -1)
    speed = np.linalg.norm(ctx.velocity, axis=-1)
    heading = ctx.heading[:, CURRENT]
    polylines: list[list[np.ndarray]] = [[np.empty((0, 2))] * n for _ in range(r)]  # each set below
    stops: list[list[list]] = [[[] for _ in range(n)] for _ in range(r)]
    lateral = np.zeros(n)
    v0 = np.zeros((r, n))
    for i in range(n):
        m = matches[i]
        if m is None:
            direction = (
                ctx.velocity[i] / speed[i] if speed[i] > 0.5 else np.array([np.cos(heading[i]), np.sin(heading[i])])
            )
            line = np.stack([pos[i], pos[i] + direction * min_length])
            for k in range(r):
                polylines[k][i] = line
            v0[:, i] = speed[i] * rng.uniform(0.9, 1.1, r)
            continue
        lane_id, seg, lat = m
        lane = ctx.lanes[lane_id]
        a, b = lane.polyline[seg], lane.polyline[seg + 1]
        t = np.clip(np.dot(pos[i] - a, b - a) / max(np.dot(b - a, b - a), 1e-9), 0, 1)
        start = a + t * (b - a)
        lateral[i] = lat
        variants: dict[tuple, tuple] = {}  # identical routes share one array (resampled once)
        for k in range(r):
            poly, agent_stops, lanes_taken = _route(ctx, lane_id, seg, start, rng, min_length)
            polylines[k][i], stops[k][i] = variants.setdefault(lanes_taken, (poly, agent_stops))
        limit = lane.speed_limit if lane.speed_limit > 0 else 11.0
        if ctx.object_type[i] == TYPE_CYCLIST:
            limit = min(limit, 6.0)
        queued = speed[i] > 0.5 or abs(lat) < 1.0  # stopped in the middle of a lane: waiting, not parked
        v0[:, i] = np.maximum(speed[i], limit * rng.uniform(0.75, 1.05, r)) if queued else 0.0
    return _Routes(polylines, stops, lateral, v0)


def _drivers(ctx: SimContext, rng: np.random.Generator, v0: np.ndarray) -> engine.Drivers:
    """The IDM parameters of each agent in each rollout (pedestrians alike, vehicles drawn at random)."""
    r, n = v0.shape
    is_ped = ctx.object_type == TYPE_PEDESTRIAN
    return engine.Drivers(
        length=np.broadcast_to(ctx.length, (r, n)).copy(),
        width=np.broadcast_to(ctx.width, (r, n)).copy(),
        v0=np.repeat(v0[..., None], NUM_FUTURE + 1, axis=-1),
        a_max=np.where(is_ped, 1.0, rng.uniform(1.0, 2.0, (r, n))),
        b_comf=np.where(is_ped, 1.5, rng.uniform(2.0, 3.0, (r, n))),
        headway=np.where(is_ped, 0.8, rng.uniform(0.9, 1.8, (r, n))),
        s0=np.where(is_ped, 0.6, rng.uniform(1.5, 2.5, (r, n))),
        margin=np.where(is_ped, 0.05, 0.3) * np.ones((r, n)),
        max_brake=np.where(is_ped, 3.0, engine.MAX_BRAKE) * np.ones((r, n)),
        moving=v0 > 0.05,  # parked agents stay put (IDM would creep towards its minimum speed)
        ignore_signals=np.broadcast_to(is_ped, (r, n)).copy(),
        blind=np.zeros((r, n, n), bool),
        crash_pairs=np.zeros((r, n, n), bool),
    )


POLICIES: dict[str, Callable[..., np.ndarray]] = {
    "constant_velocity": constant_velocity,
    "log_replay_noise": log_replay_noise,
    "idm": idm,
}


def simulate_scenario(
    scenario: scenario_pb2.Scenario, policy: str, seed: int = 0, num_rollouts: int = NUM_ROLLOUTS
) -> tuple[np.ndarray, np.ndarray]:
    """(object ids (N,), trajectories (R, N, 80, 4)) of one scenario under `policy` (sim agents)."""
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}; choose from {', '.join(POLICIES)}")
    ctx = context_from_scenario(scenario)
    return ctx.object_ids, POLICIES[policy](ctx, _rng(scenario, policy, seed), num_rollouts)


def _rng(scenario: Any, policy: str, seed: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(scenario.scenario_id.encode()), sorted(POLICIES).index(policy)])


# ---------------------------------------------------------------------------------------------
# Scenario generation: all 91 steps of every sim agent, with box sizes and types.


def _filled_history(ctx: SimContext) -> np.ndarray:
    """(N, 11, 4) logged history with gaps interpolated; before an object's first logged step,
    the straight line through its first state at its current velocity."""
    steps = np.arange(CURRENT + 1)
    hist = np.stack([ctx.x, ctx.y, ctx.z, ctx.heading], -1)
    out = hist.copy()
    for i in range(ctx.num_agents):
        known = steps[ctx.valid[i]]  # the current step is always valid for a sim agent
        for c in range(4):
            values = hist[i, known, c] if c != 3 else np.unwrap(hist[i, known, 3])
            out[i, :, c] = np.interp(steps, known, values)
        before = steps < known[0]
        out[i, before, :2] = hist[i, known[0], :2] + ((steps[before] - known[0]) * DT)[:, None] * ctx.velocity[i]
    out[..., 3] = geo.wrap_angle(out[..., 3])
    return out


def _straight_history(ctx: SimContext) -> np.ndarray:
    """(N, 11, 4): the straight line through the current state at the current velocity, heading held."""
    back = (np.arange(CURRENT + 1) - CURRENT) * DT
    x = ctx.x[:, CURRENT, None] + ctx.velocity[:, 0, None] * back
    y = ctx.y[:, CURRENT, None] + ctx.velocity[:, 1, None] * back
    z = np.broadcast_to(ctx.z[:, CURRENT, None], x.shape)
    h = np.broadcast_to(ctx.heading[:, CURRENT, None], x.shape)
    return np.stack([x, y, z, h], -1)


def _history_noise(rng: np.random.Generator, num_rollouts: int, n: int, noise_m: float) -> np.ndarray:
    """(R, N, 11, 4) smooth noise of the history, growing away from the current step (0 there)."""
    back = (CURRENT - np.arange(CURRENT + 1)) * DT
    growth = back / (NUM_FUTURE * DT)
    amp = rng.normal(0.0, noise_m, (num_rollouts, n, 2, 1))
    freq = rng.uniform(0.05, 0.25, (num_rollouts, n, 2, 1))
    phase = rng.uniform(0, 2 * np.pi, (num_rollouts, n, 2, 1))
    wave = amp * np.sin(2 * np.pi * freq * back + phase) * growth  # (R, N, 2, 11)
    out = np.zeros((num_rollouts, n, CURRENT + 1, 4))
    out[..., 0], out[..., 1] = wave[:, :, 0], wave[:, :, 1]
    out[..., 3] = rng.normal(0.0, 0.02, (num_rollouts, n, 1)) * growth
    return out


# History of each scenario-gen baseline: the logged one (filled), or the straight line.
SCENARIO_GEN_HISTORY = {"constant_velocity": "straight", "log_replay_noise": "logged_noise", "idm": "logged"}


def generate_scenario(
    scenario: scenario_pb2.Scenario, policy: str, seed: int = 0, num_rollouts: int = NUM_ROLLOUTS
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A scenario-gen baseline: (object ids (N,), trajectories (R, N, 91, 4), box sizes (N, 91, 3)
    length / width / height, object types (N,)).

    The future (steps 11-90) is the sim agents policy's; the history (steps
    0-10) is the straight line through the current state for
    `constant_velocity`, the logged history (gaps filled) for `idm`, and the
    logged history with smooth per-rollout noise for `log_replay_noise`.
    Boxes keep their current size, objects their logged type.
    """
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}; choose from {', '.join(POLICIES)}")
    ctx = context_from_scenario(scenario)
    future = POLICIES[policy](ctx, _rng(scenario, policy, seed), num_rollouts)
    kind = SCENARIO_GEN_HISTORY[policy]
    history = _straight_history(ctx) if kind == "straight" else _filled_history(ctx)
    history = np.broadcast_to(history[None], (num_rollouts,) + history.shape).copy()
    if kind == "logged_noise":
        history += _history_noise(
            np.random.default_rng([seed, zlib.crc32(scenario.scenario_id.encode()), 7]),
            num_rollouts,
            ctx.num_agents,
            noise_m=0.5,
        )
        history[..., 3] = geo.wrap_angle(history[..., 3])
    trajectories = np.concatenate([history, future], axis=2)
    sizes = np.stack([ctx.length, ctx.width, ctx.height], -1)[:, None, :]
    boxes = np.broadcast_to(sizes, (ctx.num_agents, trajectories.shape[2], 3))
    return ctx.object_ids, trajectories, boxes, ctx.object_type
