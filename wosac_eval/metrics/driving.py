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

from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.scenario import ScenarioArrays
from wosac_eval.challenges import CURRENT_TIME_INDEX, STEP_SECONDS
from wosac_eval.features.criticality import disc_gap, disc_pairs
from wosac_eval.features.metric_features import MetricFeatures

MOVING_SPEED = 0.5          # m/s: a standing SDC is not at fault
TTC_THRESHOLD = 0.95        # s
MIN_ROUTE = 1.0             # m: a logged SDC that moved less has no route to measure progress on
MIN_PROGRESS = 0.2          # below this share of the route the rollout scores 0 ("making progress")
COMFORT = {"min_acceleration": -4.05, "max_acceleration": 2.40, "max_jerk": 4.13, "max_yaw_rate": 0.95,
           "max_yaw_acceleration": 1.93}
WEIGHTS = {"progress": 5.0, "ttc": 5.0, "comfort": 2.0}
COMPONENTS = ("at_fault_collision", "collision", "offroad", "red_light", "progress", "ttc_below", "comfortable")


def route_progress(route_x: np.ndarray, route_y: np.ndarray, x: float, y: float) -> float:
    """Arc length along a polyline `(points,)` of the point nearest to (x, y)."""
    sx, sy = route_x[:-1], route_y[:-1]
    dx, dy = np.diff(route_x), np.diff(route_y)
    length2 = dx * dx + dy * dy
    with np.errstate(invalid="ignore", divide="ignore"):
        along = np.clip(np.where(length2 > 0, ((x - sx) * dx + (y - sy) * dy) / length2, 0.0), 0.0, 1.0)
    distance = np.hypot(sx + along * dx - x, sy + along * dy - y)
    k = int(np.argmin(distance))
    cumulative = np.concatenate([[0.0], np.cumsum(np.sqrt(length2))])
    return float(cumulative[k] + along[k] * np.sqrt(length2[k]))


def _box_sizes(scenario: ScenarioArrays, rollouts: RolloutArrays, r: int) -> tuple[np.ndarray, np.ndarray]:
    """length, width float64 `(num_objects, num_steps)` of rollout r's objects (logged sizes for sim agents)."""
    if rollouts.has_boxes:
        return (np.asarray(rollouts.length[r], np.float64), np.asarray(rollouts.width[r], np.float64))
    # Sim agents: the logged size at the current step, as the evaluator takes it.
    log = scenario.log.take_ids(rollouts.object_id[r])
    shape = np.shape(rollouts.x[r])
    return tuple(np.broadcast_to(np.asarray(a[:, CURRENT_TIME_INDEX], np.float64)[:, None], shape)
                 for a in (log.length, log.width))


def at_fault(rollouts: RolloutArrays, sizes, r: int, steps: np.ndarray, sdc: int, speed: np.ndarray) -> bool:
    """Whether the SDC (row `sdc` of rollout r) is at fault in a collision at any of `steps` (simulated).

    At a step where the SDC moves, its partner is the nearest other object (three discs each); a partner
    whose centre is behind the SDC's rear bumper rear-ended it.
    """
    steps = np.asarray(steps)[np.asarray(speed) > MOVING_SPEED]
    num_objects = rollouts.x.shape[1]
    if steps.size == 0 or num_objects < 2:
        return False
    others = np.flatnonzero(np.arange(num_objects) != sdc)
    x, y, heading = (np.asarray(a[r][:, steps], np.float64) for a in (rollouts.x, rollouts.y, rollouts.heading))
    length, width = (a[:, steps] for a in sizes)
    pairs = np.ix_(others, np.arange(steps.size))
    me = lambda a: np.broadcast_to(a[sdc], (others.size, steps.size)).ravel()  # noqa: E731
    dx, dy, radius = disc_pairs((x[pairs] - x[sdc]).ravel(), (y[pairs] - y[sdc]).ravel(), me(heading), me(length),
                                me(width), heading[pairs].ravel(), length[pairs].ravel(), width[pairs].ravel())
    partner = others[np.argmin(disc_gap(dx, dy, radius).reshape(others.size, steps.size), axis=0)]
    columns = np.arange(steps.size)
    along = ((x[partner, columns] - x[sdc]) * np.cos(heading[sdc])
             + (y[partner, columns] - y[sdc]) * np.sin(heading[sdc]))
    return bool((along > -length[sdc] / 2).any())


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
    return (_within(acceleration, valid, COMFORT["min_acceleration"], COMFORT["max_acceleration"])
            & _within(jerk, valid, -COMFORT["max_jerk"], COMFORT["max_jerk"])
            & _within(sim.angular_speed[:, e], valid, -COMFORT["max_yaw_rate"], COMFORT["max_yaw_rate"])
            & _within(sim.angular_acceleration[:, e], valid, -COMFORT["max_yaw_acceleration"],
                      COMFORT["max_yaw_acceleration"]))


def route_progress_share(route_x: np.ndarray, route_y: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per rollout: how far along the logged route its final position lies, as a share of the route, in [0, 1]."""
    length = float(np.hypot(np.diff(route_x), np.diff(route_y)).sum()) if route_x.size > 1 else 0.0
    if length < MIN_ROUTE:
        return np.ones(np.shape(x))
    return np.array([np.clip(route_progress(route_x, route_y, float(a), float(b)) / length, 0.0, 1.0)
                     for a, b in zip(x, y)])


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
    speed = np.asarray(sim.linear_speed[:, e])
    sizes = None
    fault = np.zeros(rollouts.num_rollouts, dtype=bool)
    for r in np.flatnonzero(collision.any(axis=-1)):
        if sizes is None or not np.array_equal(rollouts.object_id[r], rollouts.object_id[0]):
            sizes = _box_sizes(scenario, rollouts, r)
        steps = np.flatnonzero(collision[r])
        fault[r] = at_fault(rollouts, sizes if not rollouts.has_boxes else _box_sizes(scenario, rollouts, r), r,
                            offset + steps, rows[r], speed[r, steps])
    events = {"at_fault_collision": fault, "collision": collision.any(axis=-1),
              "offroad": (np.asarray(sim.offroad_per_step[:, e], dtype=bool) & valid).any(axis=-1),
              "red_light": (np.asarray(sim.traffic_light_violation_per_step[:, e], dtype=bool) & valid).any(axis=-1)}
    ttc = np.asarray(sim.time_to_collision[:, e], dtype=np.float64)
    ttc_below = (valid & (ttc < TTC_THRESHOLD)).any(axis=-1)
    last = rollouts.num_steps - 1
    progress = route_progress_share(log.x[0, CURRENT_TIME_INDEX:][route].astype(np.float64),
                                    log.y[0, CURRENT_TIME_INDEX:][route].astype(np.float64),
                                    np.asarray(rollouts.x)[np.arange(rows.size), rows, last],
                                    np.asarray(rollouts.y)[np.arange(rows.size), rows, last])
    comfort = comfortable(sim, e, valid)
    multiplier = ~events["at_fault_collision"] & ~events["offroad"] & ~events["red_light"] & (progress >= MIN_PROGRESS)
    weighted = (WEIGHTS["progress"] * progress + WEIGHTS["ttc"] * ~ttc_below
                + WEIGHTS["comfort"] * comfort) / sum(WEIGHTS.values())
    score = multiplier * weighted
    per_rollout = {**events, "progress": progress, "ttc_below": ttc_below, "comfortable": comfort}
    return {"score": float(score.mean()),
            "components": {k: float(np.mean(per_rollout[k], dtype=np.float64)) for k in COMPONENTS}}
