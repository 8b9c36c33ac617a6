"""Driving scores of the self-driving car (SDC), nuPlan-style: how well it drove, not how realistic the scene is.

Per rollout, from the simulated SDC (the same per-step features as the
realism metrics, over its valid steps):

    at_fault_collision  a collision while the SDC moves (> 0.5 m/s) and the other object is not behind it
                        (its centre behind the SDC's rear bumper: a rear-end by the other is not the SDC's fault)
    collision           any collision
    offroad             any step off the road
    red_light           a red light run
    progress            how far along the logged route the SDC ends, as a share of how far the logged SDC got
                        (its final position projected on the logged path from the current step on; 1 when the
                        logged SDC moved less than 1 m), clipped to [0, 1]
    ttc_below           its time to collision fell below 0.95 s
    comfortable         longitudinal acceleration within [-4.05, 2.40] m/s^2, jerk within 4.13 m/s^3, yaw rate
                        within 0.95 rad/s and yaw acceleration within 1.93 rad/s^2 at every step (nuPlan's limits)

    rollout score = (1 - at_fault_collision) (1 - offroad) (1 - red_light) [progress >= 0.2]
                    x (5 progress + 5 (1 - ttc_below) + 2 comfortable) / 12

`driving.score` and every component are means over the rollouts (rates for
the events). These are diagnostics of a driving policy beside the WOSAC
realism metrics, not part of them.
"""

from __future__ import annotations

import numpy as np

from wosac_eval.analysis.criticality_features import disc_gap, disc_pairs
from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.scenario import ScenarioArrays
from wosac_eval.arrays.trajectories import index_of_ids
from wosac_eval.challenges import CURRENT_TIME_INDEX, STEP_SECONDS
from wosac_eval.features.metric_features import MetricFeatures

MOVING_SPEED = 0.5  # m/s: a standing SDC is not at fault
TTC_THRESHOLD = 0.95  # s
MIN_ROUTE = 1.0  # m: a logged SDC that moved less has no route to measure progress on
MIN_PROGRESS = 0.2  # below this share of the route the rollout scores 0 ("making progress")
COMFORT = {
    "min_acceleration": -4.05,
    "max_acceleration": 2.40,
    "max_jerk": 4.13,
    "max_yaw_rate": 0.95,
    "max_yaw_acceleration": 1.93,
}
WEIGHTS = {"progress": 5.0, "ttc": 5.0, "comfort": 2.0}
COMPONENTS = ("at_fault_collision", "collision", "offroad", "red_light", "progress", "ttc_below", "comfortable")


def route_progress(route_x: np.ndarray, route_y: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Arc length along a polyline `(num_points,)` of the point nearest to each (x, y), float64 like `x`."""
    x, y = np.asarray(x, np.float64)[..., None], np.asarray(y, np.float64)[..., None]
    sx, sy = route_x[:-1], route_y[:-1]
    dx, dy = np.diff(route_x), np.diff(route_y)
    length2 = dx * dx + dy * dy
    with np.errstate(invalid="ignore", divide="ignore"):
        along = np.clip(np.where(length2 > 0, ((x - sx) * dx + (y - sy) * dy) / length2, 0.0), 0.0, 1.0)
    distance = np.hypot(sx + along * dx - x, sy + along * dy - y)
    k = np.argmin(distance, axis=-1)
    cumulative = np.concatenate([[0.0], np.cumsum(np.sqrt(length2))])
    return cumulative[k] + np.take_along_axis(along, k[..., None], axis=-1)[..., 0] * np.sqrt(length2[k])


def _box_sizes(scenario: ScenarioArrays, rollouts: RolloutArrays) -> tuple[np.ndarray, np.ndarray]:
    """length, width `(num_rollouts, num_objects, 1 or num_steps)` of the rollouts' objects (sim agents: the
    logged size at the current step, as the evaluator takes it)."""
    if rollouts.has_boxes:
        return np.asarray(rollouts.length), np.asarray(rollouts.width)
    ids = np.asarray(rollouts.object_id)
    rows = index_of_ids(scenario.log.object_id, ids.reshape(-1)).reshape(ids.shape)
    return tuple(
        np.asarray(a, np.float32)[rows, CURRENT_TIME_INDEX][..., None]
        for a in (scenario.log.length, scenario.log.width)
    )


# Metres added to the bound below which objects are tried as partners: far above float64's rounding of
# the bounds, so no object that could be the nearest is left out.
_PARTNER_SLACK = 1e-6


def at_fault(
    rollouts: RolloutArrays,
    sizes: tuple[np.ndarray, np.ndarray],
    rollout: np.ndarray,
    step: np.ndarray,
    sdc: np.ndarray,
) -> np.ndarray:
    """Whether the SDC is at fault in its collision, per (rollout, simulated step) entry, bool `(batch,)`.

    Its partner is the nearest other object (three discs each, the lowest row among ties); a partner whose
    centre is behind the SDC's rear bumper rear-ended it. `sdc` is the SDC's row in each entry's rollout.
    """
    pick = lambda a: np.asarray(np.broadcast_to(a, rollouts.x.shape)[rollout, :, step], np.float64)  # noqa: E731
    x, y, heading, length, width = map(pick, (rollouts.x, rollouts.y, rollouts.heading, *sizes))  # (entries, objects)
    entries = np.arange(rollout.size)
    dxc, dyc = x - x[entries, sdc][:, None], y - y[entries, sdc][:, None]
    # A box's discs lie within `reach` of its centre and its middle disc is the centre, so a pair's disc gap
    # is at least their centres' distance less both reaches and the radii, and at most that distance less
    # the radii. Only objects whose least gap can reach the entry's least most are measured disc by disc:
    # their gaps are the same arithmetic as over every object, the others cannot be the nearest (NaN
    # bounds keep an object in).
    centre = np.hypot(dxc, dyc)
    radius = (width + width[entries, sdc][:, None]) / 2
    reach = np.maximum(length - width, 0.0) / 2
    most = np.maximum(centre - radius, 0.0)
    most[entries, sdc] = np.inf
    least = np.maximum(centre - reach - reach[entries, sdc][:, None] - radius, 0.0)
    tried = ~(least > most.min(axis=1, keepdims=True) + _PARTNER_SLACK)
    tried[entries, sdc] = False
    e, j = np.nonzero(tried)
    me = sdc[e]
    dx, dy, radii = disc_pairs(
        dxc[e, j], dyc[e, j], heading[e, me], length[e, me], width[e, me], heading[e, j], length[e, j], width[e, j]
    )
    gap = np.full(x.shape, np.inf)
    gap[e, j] = disc_gap(dx, dy, radii)
    partner = np.argmin(gap, axis=1)
    along = (x[entries, partner] - x[entries, sdc]) * np.cos(heading[entries, sdc]) + (
        y[entries, partner] - y[entries, sdc]
    ) * np.sin(heading[entries, sdc])
    return along > -length[entries, sdc] / 2


def rollouts_at_fault(
    rollouts: RolloutArrays,
    sizes: tuple[np.ndarray, np.ndarray],
    rollout: np.ndarray,
    step: np.ndarray,
    sdc_rows: np.ndarray,
) -> np.ndarray:
    """Whether the SDC is at fault in any of its collision entries, per rollout, bool `(num_rollouts,)`.

    rollout, step: the entries `(batch,)`, rollout by rollout, steps ascending (`np.nonzero`'s order);
    sdc_rows: the SDC's row in each rollout `(num_rollouts,)`. The entries are tested in rounds, each
    rollout's first entry, then its next 4, 16, ...: a rollout found at fault is not tested further (a
    poor policy's SDC collides at most of its steps, and one entry at fault decides its rollout).
    """
    fault = np.zeros(rollouts.num_rollouts, dtype=bool)
    if rollout.size == 0:
        return fault
    rank = np.arange(rollout.size) - np.searchsorted(rollout, rollout)  # each entry's place in its rollout
    low, width, last = 0, 1, rank.max()
    while low <= last:
        tested = (rank >= low) & (rank < low + width) & ~fault[rollout]
        if tested.any():
            r = rollout[tested]
            np.logical_or.at(fault, r, at_fault(rollouts, sizes, r, step[tested], sdc_rows[r]))
        low, width = low + width, width * 4
    return fault


def _within(values: np.ndarray, valid: np.ndarray, low: float, high: float) -> np.ndarray:
    """Per rollout: every valid finite value of `(num_rollouts, num_steps)` lies in [low, high]."""
    values = np.asarray(values, dtype=np.float64)
    outside = valid & np.isfinite(values) & ((values < low) | (values > high))
    return ~outside.any(axis=-1)


def comfortable(sim: MetricFeatures, e: int, valid: np.ndarray) -> np.ndarray:
    """Per rollout: the SDC (column e) kept nuPlan's comfort limits at every valid step, bool `(num_rollouts,)`."""
    acceleration = np.asarray(sim.linear_acceleration[:, e], dtype=np.float64)
    jerk = np.full(acceleration.shape, np.nan)
    jerk[:, 1:-1] = (acceleration[:, 2:] - acceleration[:, :-2]) / (2 * STEP_SECONDS)
    return (
        _within(acceleration, valid, COMFORT["min_acceleration"], COMFORT["max_acceleration"])
        & _within(jerk, valid, -COMFORT["max_jerk"], COMFORT["max_jerk"])
        & _within(sim.angular_speed[:, e], valid, -COMFORT["max_yaw_rate"], COMFORT["max_yaw_rate"])
        & _within(
            sim.angular_acceleration[:, e], valid, -COMFORT["max_yaw_acceleration"], COMFORT["max_yaw_acceleration"]
        )
    )


def route_progress_share(route_x: np.ndarray, route_y: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per rollout: how far along the logged route its final position lies, as a share of the route, in [0, 1]."""
    length = float(np.hypot(np.diff(route_x), np.diff(route_y)).sum()) if route_x.size > 1 else 0.0
    if length < MIN_ROUTE:
        return np.ones(np.shape(x))
    return np.clip(route_progress(route_x, route_y, x, y) / length, 0.0, 1.0)


def driving_scores(scenario: ScenarioArrays, rollouts: RolloutArrays, sim: MetricFeatures) -> dict | None:
    """The SDC's driving scores over the rollouts (see the module), or None when the SDC is not evaluated."""
    sdc = scenario.sdc_id
    evaluated = np.flatnonzero(np.asarray(sim.object_id) == sdc)
    if sdc < 0 or evaluated.size == 0:
        return None
    e = int(evaluated[0])
    log = scenario.log.take_ids([sdc])
    route = log.valid[0, CURRENT_TIME_INDEX:]
    valid = np.asarray(sim.valid[:, e], dtype=bool)  # (num_rollouts, num_feature_steps)
    rows = np.array([int(np.flatnonzero(ids == sdc)[0]) for ids in np.asarray(rollouts.object_id)])
    collision = np.asarray(sim.collision_per_step[:, e], dtype=bool) & valid
    # Feature steps are the rollout's last steps (sim agents: after the history).
    offset = rollouts.num_steps - valid.shape[-1]
    # At-fault tests, all rollouts at once: the collision steps where the SDC moves.
    rollout, step = np.nonzero(collision & (np.asarray(sim.linear_speed[:, e]) > MOVING_SPEED))
    fault = np.zeros(rollouts.num_rollouts, dtype=bool)
    if rollout.size and rollouts.x.shape[1] > 1:
        fault = rollouts_at_fault(rollouts, _box_sizes(scenario, rollouts), rollout, offset + step, rows)
    events = {
        "at_fault_collision": fault,
        "collision": collision.any(axis=-1),
        "offroad": (np.asarray(sim.offroad_per_step[:, e], dtype=bool) & valid).any(axis=-1),
        "red_light": (np.asarray(sim.traffic_light_violation_per_step[:, e], dtype=bool) & valid).any(axis=-1),
    }
    ttc = np.asarray(sim.time_to_collision[:, e], dtype=np.float64)
    ttc_below = (valid & (ttc < TTC_THRESHOLD)).any(axis=-1)
    last = rollouts.num_steps - 1
    progress = route_progress_share(
        log.x[0, CURRENT_TIME_INDEX:][route].astype(np.float64),
        log.y[0, CURRENT_TIME_INDEX:][route].astype(np.float64),
        np.asarray(rollouts.x)[np.arange(rows.size), rows, last],
        np.asarray(rollouts.y)[np.arange(rows.size), rows, last],
    )
    comfort = comfortable(sim, e, valid)
    multiplier = ~events["at_fault_collision"] & ~events["offroad"] & ~events["red_light"] & (progress >= MIN_PROGRESS)
    weighted = (WEIGHTS["progress"] * progress + WEIGHTS["ttc"] * ~ttc_below + WEIGHTS["comfort"] * comfort) / sum(
        WEIGHTS.values()
    )
    score = multiplier * weighted
    per_rollout = {**events, "progress": progress, "ttc_below": ttc_below, "comfortable": comfort}
    return {
        "score": float(score.mean()),
        "components": {k: float(np.mean(per_rollout[k], dtype=np.float64)) for k in COMPONENTS},
    }
