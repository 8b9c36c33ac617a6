"""How demanding a logged scene is, step by step: kinematic volatility, interaction, and the behaviour to rate.

From the logged trajectories of the sim agents (objects valid at the current
step) alone, over all 91 steps:

- kinematic volatility of vehicles and cyclists: hard braking (deceleration,
  m/s^2), jerk (|d acceleration / dt|, m/s^3) and the yaw acceleration of
  moving objects (|d yaw rate / dt|, rad/s^2). Rates are central differences
  over +-0.2 s (`RATE_HALF_WINDOW` steps): logged positions are noisy, and a
  one-step difference of a difference of a difference measures the noise;
- interaction between pairs of objects, at least one of them not a pedestrian,
  whose centres are less than `PAIR_RANGE` apart: objects are three discs along
  their length (radius half the width); the gap is the least distance between
  discs; the time to collision the first time two discs touch at constant
  velocities (within `TTC_HORIZON`, pairs already touching or moving apart
  slower than 1 m/s left out); the closing speed that of pairs on such a
  collision course; the near miss exp(-gap / 0.5 m) x v / (v + 2 m/s), with v
  the relative speed;
- the map, for vehicles that move (faster than `MOVING_SPEED` at some step):
  how far their centres leave the road (the official signed road-edge
  distance, every `OFFROAD_STRIDE` steps, m) and whether they cross a stop
  line at a red light (the official red-light test);
- behaviour: every valid (acceleration, yaw rate) sample of vehicles and
  cyclists, binned by `BEHAVIOUR_BINS`, to rate how unusual a scene's behaviour
  is against a scenario set (`analysis.criticality_scores`).

Each per-step series is the worst value over objects (or pairs) at that step:
NaN where no object qualifies, inf (time to collision) or 0 where no pair does.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numba
import numpy as np

from wosac_eval.arrays.object_types import TYPE_CYCLIST, TYPE_PEDESTRIAN, TYPE_VEHICLE
from wosac_eval.arrays.scenario import ScenarioArrays, TrafficSignals
from wosac_eval.arrays.trajectories import ObjectTrajectories
from wosac_eval.challenges import STEP_SECONDS
from wosac_eval.features.metric_features import MapContext, map_context
from wosac_eval.features.road_edge import signed_distance_to_polylines
from wosac_eval.features.search import PrunedSearch

RATE_HALF_WINDOW = 2  # steps each side of a central difference
MOVING_SPEED = 2.0  # m/s: the yaw of slower objects is mostly heading noise
PAIR_RANGE = 25.0  # m between centres: farther pairs do not interact within a step
TTC_HORIZON = 5.0  # s
MIN_CLOSING = 1.0  # m/s of relative speed for a collision course
NEAR_MISS_GAP = 0.5  # m: the gap scale of the near miss
NEAR_MISS_SPEED = 2.0  # m/s: the relative speed at which the near miss counts half
OFFROAD_STRIDE = 5  # steps between off-road tests: an excursion worth noting lasts longer than 0.5 s
# (acceleration m/s^2, yaw rate rad/s) bins of the behaviour histogram; values beyond clip to the end bins.
BEHAVIOUR_BINS = (np.linspace(-8.0, 8.0, 33), np.linspace(-1.0, 1.0, 41))


@dataclasses.dataclass(frozen=True)
class CriticalityFeatures:
    """Per-step worst values of a logged scene, and its behaviour histogram.

    Attributes:
      braking, jerk, yaw_acceleration: float64 `(num_steps,)`, the worst over vehicles and cyclists.
      time_to_collision: float64 `(num_steps,)` seconds, the least over pairs (inf: none on a collision course).
      closing_speed: float64 `(num_steps,)` m/s, the most over pairs on a collision course (0: none).
      near_miss: float64 `(num_steps,)` in [0, 1], the worst over pairs.
      offroad: float64 `(num_steps,)` m of the worst moving vehicle's centre beyond the road edge (NaN: not
        tested then; -inf: no valid vehicle).
      red_light: bool `(num_steps,)`, a moving vehicle crossing a stop line at a red light.
      behaviour: int64 `(32, 40)` (acceleration, yaw rate) sample counts.
    """

    braking: np.ndarray
    jerk: np.ndarray
    yaw_acceleration: np.ndarray
    time_to_collision: np.ndarray
    closing_speed: np.ndarray
    near_miss: np.ndarray
    offroad: np.ndarray
    red_light: np.ndarray
    behaviour: np.ndarray


def central_rate(
    values: np.ndarray, valid: np.ndarray, half: int = RATE_HALF_WINDOW, wrap: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """(v[t + half] - v[t - half]) / (2 half dt) and its validity, `(..., num_steps)` each (NaN / False at the ends).

    wrap: the values are angles; their difference is wrapped to [-pi, pi).
    """
    out = np.full(values.shape, np.nan)
    ok = np.zeros(values.shape, dtype=bool)
    if values.shape[-1] > 2 * half:
        delta = values[..., 2 * half :] - values[..., : -2 * half]
        if wrap:
            delta = np.mod(delta + np.pi, 2 * np.pi) - np.pi
        out[..., half:-half] = delta / (2 * half * STEP_SECONDS)
        ok[..., half:-half] = valid[..., 2 * half :] & valid[..., : -2 * half]
    return out, ok


def _worst(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The max over objects (axis 0) of the valid values, NaN where none is valid."""
    masked = np.where(valid, values, -np.inf).max(axis=0, initial=-np.inf)
    return np.where(np.isneginf(masked), np.nan, masked)


def kinematic_volatility(
    log: ObjectTrajectories, moving_types: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per-step braking, jerk and yaw acceleration of the objects of `moving_types`, and the behaviour histogram.

    Returns:
      (braking, jerk, yaw_acceleration, behaviour, velocity): float64 `(num_steps,)` x 3, int64 counts, and
      (vx, vy, valid) `(num_objects, num_steps)` for the interaction.
    """
    x, y, heading = (np.asarray(a, dtype=np.float64) for a in (log.x, log.y, log.heading))
    vx, v_valid = central_rate(x, log.valid)
    vy, _ = central_rate(y, log.valid)
    speed = np.hypot(vx, vy)
    accel, a_valid = central_rate(speed, v_valid)
    jerk, j_valid = central_rate(accel, a_valid)
    yaw_rate, w_valid = central_rate(heading, log.valid, wrap=True)
    yaw_accel, wa_valid = central_rate(yaw_rate, w_valid)
    rows = moving_types[:, None]
    braking = _worst(-accel, a_valid & rows)
    jerk_worst = _worst(np.abs(jerk), j_valid & rows)
    yaw_worst = _worst(np.abs(yaw_accel), wa_valid & rows & (speed > MOVING_SPEED))
    sampled = a_valid & w_valid & rows
    a_edges, w_edges = BEHAVIOUR_BINS
    behaviour, _, _ = np.histogram2d(
        np.clip(accel[sampled], a_edges[0], a_edges[-1]),
        np.clip(yaw_rate[sampled], w_edges[0], w_edges[-1]),
        bins=(a_edges, w_edges),
    )
    return braking, jerk_worst, yaw_worst, behaviour.astype(np.int64), (vx, vy, v_valid)


_DISC = np.array([-1.0, 0.0, 1.0], dtype=np.float32)  # rear, middle and front disc along the length


def _disc_offsets(heading: Any, length: Any, width: Any) -> tuple[np.ndarray, np.ndarray]:
    """The x and y offsets `(batch,)` from a box's centre to its front disc (the rear one is opposite)."""
    offset = np.maximum(length - width, 0.0) / 2
    return np.cos(heading) * offset, np.sin(heading) * offset


def disc_pairs(
    dxc: np.ndarray,
    dyc: np.ndarray,
    heading_a: np.ndarray,
    length_a: np.ndarray,
    width_a: np.ndarray,
    heading_b: np.ndarray,
    length_b: np.ndarray,
    width_b: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre-to-centre vectors of every (disc of a, disc of b) pair, `(batch, 3, 3)` x and y, and the radii sum.

    dxc, dyc: `(batch,)` from a's centre to b's; the rest `(batch,)`.
    """
    oxa, oya = _disc_offsets(heading_a, length_a, width_a)
    oxb, oyb = _disc_offsets(heading_b, length_b, width_b)
    dx = dxc[:, None, None] + oxb[:, None, None] * _DISC[None, None, :] - oxa[:, None, None] * _DISC[None, :, None]
    dy = dyc[:, None, None] + oyb[:, None, None] * _DISC[None, None, :] - oya[:, None, None] * _DISC[None, :, None]
    return dx, dy, ((width_a + width_b) / 2)[:, None, None]


def disc_gap(dx: np.ndarray, dy: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """The gap between two boxes as three discs each (0 when they touch), `(batch,)`."""
    return np.maximum(np.sqrt((dx * dx + dy * dy).min(axis=(1, 2))) - radius[:, 0, 0], 0.0)


def interacting_pairs(
    x: np.ndarray, y: np.ndarray, valid: np.ndarray, pedestrian: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of objects that can interact: (first, second) int `(num_pairs,)`, first < second, in
    `np.triu_indices` order, both valid at some step, not both pedestrians, and whose valid positions'
    bounding boxes come within PAIR_RANGE (farther paths never interact: most pairs of a large scene,
    dropped before any per-step work).

    x, y: float64 `(num_objects, num_steps)`; valid: bool `(num_objects, num_steps)`; pedestrian: bool
    `(num_objects,)`.
    """
    i, j = np.triu_indices(x.shape[0], k=1)
    valid_xy = np.asarray(valid.any(axis=1))  # an array: numpy's stubs allow a scalar
    with np.errstate(invalid="ignore"):
        low_x, high_x = (np.where(valid, x, np.inf).min(axis=1), np.where(valid, x, -np.inf).max(axis=1))
        low_y, high_y = (np.where(valid, y, np.inf).min(axis=1), np.where(valid, y, -np.inf).max(axis=1))
    gap_x = np.maximum(low_x[j] - high_x[i], low_x[i] - high_x[j])
    gap_y = np.maximum(low_y[j] - high_y[i], low_y[i] - high_y[j])
    close_paths = valid_xy[i] & valid_xy[j] & (np.hypot(np.maximum(gap_x, 0.0), np.maximum(gap_y, 0.0)) < PAIR_RANGE)
    keep = close_paths & ~(pedestrian[i] & pedestrian[j])
    return i[keep], j[keep]


def pairwise_interaction(
    log: ObjectTrajectories, velocity: tuple[np.ndarray, np.ndarray, np.ndarray], pedestrian: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-step least time to collision, most closing speed and worst near miss over pairs of objects.

    Returns:
      float64 `(num_steps,)` each (see `CriticalityFeatures`).
    """
    vx, vy, v_valid = velocity
    x, y, heading = (np.asarray(a, dtype=np.float64) for a in (log.x, log.y, log.heading))
    length, width = np.asarray(log.length, np.float64), np.asarray(log.width, np.float64)
    n, steps = x.shape
    ttc, closing, near = np.full(steps, np.inf), np.zeros(steps), np.zeros(steps)
    if n < 2:
        return ttc, closing, near
    a, b = interacting_pairs(x, y, v_valid, pedestrian)
    # Two objects that both stand still neither close in nor miss each other: most pairs of a car park.
    moving = v_valid & (np.hypot(vx, vy) >= MIN_CLOSING / 2)
    # The front disc's offsets of every box at every step, as `disc_pairs` takes them (numpy's sine and
    # cosine: the compiled loop repeats numpy's arithmetic, not its library's transcendentals).
    offset = np.maximum(length - width, 0.0) / 2
    offset_x, offset_y = np.cos(heading) * offset, np.sin(heading) * offset
    step, gap, relative_speed = _pair_entries(
        a, b, x, y, vx, vy, v_valid, moving, length, width, offset_x, offset_y, ttc, closing
    )
    # exp by numpy, as the ufunc computes it (the compiled loop's exp may round differently).
    np.maximum.at(near, step, np.exp(-gap / NEAR_MISS_GAP) * relative_speed / (relative_speed + NEAR_MISS_SPEED))
    return ttc, closing, near


@numba.njit(cache=True, error_model="numpy")  # float division by zero gives inf or NaN, as numpy's
def _pair_entries(
    pair_a: Any,
    pair_b: Any,
    x: Any,
    y: Any,
    vx: Any,
    vy: Any,
    v_valid: Any,
    moving: Any,
    length: Any,
    width: Any,
    offset_x: Any,
    offset_y: Any,
    ttc: Any,
    closing: Any,
) -> Any:
    """The (pair, step) entries that can matter, as `pairwise_interaction` defines them, pair by pair and step
    by step: lowers `ttc` and raises `closing` in place; returns each entry's step, disc gap and relative speed
    (for the near miss). The arithmetic is numpy's on float64, operation by operation (NaN and ties alike)."""
    capacity = 1024
    out_step = np.empty(capacity, np.int64)
    out_gap = np.empty(capacity, np.float64)
    out_speed = np.empty(capacity, np.float64)
    n = 0
    discs = (-1.0, 0.0, 1.0)  # rear, middle and front disc along the length (`_DISC`)
    for p in range(pair_a.shape[0]):
        a, b = pair_a[p], pair_b[p]
        for t in range(x.shape[1]):
            if not (v_valid[a, t] and v_valid[b, t] and (moving[a, t] or moving[b, t])):
                continue
            dxc, dyc = x[b, t] - x[a, t], y[b, t] - y[a, t]
            ux, uy = vx[b, t] - vx[a, t], vy[b, t] - vy[a, t]
            speed = np.hypot(ux, uy)
            centre = np.hypot(dxc, dyc)
            limit = TTC_HORIZON * speed
            if not (limit != limit or limit > 3.0):  # np.maximum(3.0, limit), NaN kept
                limit = 3.0
            if not (centre - (length[a, t] + length[b, t]) / 2 < limit and centre < PAIR_RANGE):
                continue
            radius = (width[a, t] + width[b, t]) / 2
            speed2 = speed * speed
            least = np.inf
            nan = False
            entry_ttc = np.inf
            for da in discs:
                for db in discs:
                    dx = dxc + offset_x[b, t] * db - offset_x[a, t] * da
                    dy = dyc + offset_y[b, t] * db - offset_y[a, t] * da
                    distance2 = dx * dx + dy * dy
                    if distance2 != distance2:
                        nan = True
                    elif distance2 < least:
                        least = distance2
                    approach = dx * ux + dy * uy
                    c = distance2 - radius * radius
                    disc = approach * approach - speed2 * c
                    root = disc if (disc != disc or disc >= 0.0) else 0.0  # np.maximum(disc, 0.0)
                    t_hit = (-approach - np.sqrt(root)) / speed2
                    course = c > 0 and approach < 0 and disc >= 0 and t_hit <= TTC_HORIZON
                    if course and speed2 >= MIN_CLOSING * MIN_CLOSING and t_hit < entry_ttc:
                        entry_ttc = t_hit
            gap = np.nan if nan else np.sqrt(least) - radius
            if not (gap != gap or gap >= 0.0):  # np.maximum(gap, 0.0)
                gap = 0.0
            if entry_ttc < ttc[t]:
                ttc[t] = entry_ttc
            if entry_ttc < np.inf and speed > closing[t]:
                closing[t] = speed
            if n == capacity:
                capacity *= 2
                out_step = _grown(out_step, capacity)
                out_gap = _grown(out_gap, capacity)
                out_speed = _grown(out_speed, capacity)
            out_step[n], out_gap[n], out_speed[n] = t, gap, speed
            n += 1
    return out_step[:n], out_gap[:n], out_speed[:n]


@numba.njit(inline="always")
def _grown(values: Any, capacity: Any) -> Any:
    out = np.empty(capacity, values.dtype)
    out[: values.shape[0]] = values
    return out


def map_events(
    log: ObjectTrajectories, movers: np.ndarray, context: MapContext, signals: TrafficSignals | None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-step off-road distance (m, NaN between tested steps) and red-light running of the moving vehicles."""
    steps = log.num_steps
    offroad, red = np.full(steps, np.nan), np.zeros(steps, dtype=bool)
    if not movers.any():
        return offroad, red
    cars = log.take_objects(np.flatnonzero(movers))
    search = PrunedSearch(context.road_edges, context.lanes, signals)
    tested = cars.take_steps(slice(0, steps, OFFROAD_STRIDE))
    # The bottom centre of each valid box: the corners' test would cost four times as much.
    points = np.stack([tested.x, tested.y, tested.z - tested.height * np.float32(0.5)], axis=-1)[tested.valid]
    edge = np.full(tested.valid.shape, -np.inf)
    if len(points) and context.road_edges is not None:
        edge[tested.valid] = signed_distance_to_polylines(context.road_edges, points.astype(np.float32))
    offroad[::OFFROAD_STRIDE] = edge.max(axis=0)
    if signals is not None and context.lanes is not None:
        red = search.red_light_violation(cars.x[None], cars.y[None], cars.valid[None])[0].any(axis=0)
    return offroad, red


def criticality_features(scenario: ScenarioArrays, context: MapContext | None = None) -> CriticalityFeatures:
    """The per-step criticality series and behaviour histogram of a scenario's logged sim agents.

    context: the scenario's `MapContext` when the caller has built it already (scoring has).
    """
    log = scenario.log.take_ids(scenario.sim_agent_ids)
    types = np.asarray(log.object_type)
    moving = np.isin(types, (TYPE_VEHICLE, TYPE_CYCLIST))
    braking, jerk, yaw_acceleration, behaviour, velocity = kinematic_volatility(log, moving)
    ttc, closing, near_miss = pairwise_interaction(log, velocity, types == TYPE_PEDESTRIAN)
    vx, vy, v_valid = velocity
    movers = (types == TYPE_VEHICLE) & (np.where(v_valid, np.hypot(vx, vy), 0.0) > MOVING_SPEED).any(axis=1)
    offroad, red_light = map_events(log, movers, context or map_context(scenario), scenario.signals)
    return CriticalityFeatures(braking, jerk, yaw_acceleration, ttc, closing, near_miss, offroad, red_light, behaviour)


def compile_loops() -> None:
    """Compiles `pairwise_interaction`'s loop now (or loads it from numba's cache), for the argument types
    scoring passes: called by `scoring.warm_up.compile_loops`."""
    f, b, i = np.zeros((2, 3)), np.ones((2, 3), bool), np.zeros(1, np.int64)
    _pair_entries(i, i + 1, f, f, f, f, b, b, f + 4, f + 2, f, f, np.full(3, np.inf), np.zeros(3))
