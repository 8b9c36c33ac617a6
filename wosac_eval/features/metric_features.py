"""All per-step features of one scenario, for the log and for the rollouts.

Feature arrays have shape `(num_samples, num_evaluated, 80)`: one sample for
the log, one per rollout for the simulation. Every kernel sees trajectories of
91 steps (history prepended to the future) laid out in the official object
order: evaluated objects (sorted ids) first, then the other sim agents.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.scenario import CURRENT_TIME_INDEX, STEP_SECONDS, ScenarioArrays
from wosac_eval.arrays.trajectories import ObjectTrajectories, index_of_ids
from wosac_eval.features import box_geometry, interaction, kinematics, road_edge, traffic_lights

_F = np.float32
FUTURE = slice(CURRENT_TIME_INDEX + 1, None)


@dataclasses.dataclass(frozen=True)
class MetricFeatures:
    """Features of the evaluated objects.

    Attributes:
      object_id: int64 `(num_evaluated,)`.
      object_type: int32 `(num_samples, num_evaluated)`.
      valid: bool `(num_samples, num_evaluated, num_steps)`.
      average_displacement_error: float32 `(num_samples, num_evaluated)`.
      linear_speed, linear_acceleration, angular_speed, angular_acceleration,
      distance_to_nearest_object, time_to_collision, distance_to_road_edge:
        float32 `(num_samples, num_evaluated, num_steps)`.
      collision_per_step, offroad_per_step, traffic_light_violation_per_step:
        bool `(num_samples, num_evaluated, num_steps)`.
    """

    object_id: np.ndarray
    object_type: np.ndarray
    valid: np.ndarray
    average_displacement_error: np.ndarray
    linear_speed: np.ndarray
    linear_acceleration: np.ndarray
    angular_speed: np.ndarray
    angular_acceleration: np.ndarray
    distance_to_nearest_object: np.ndarray
    collision_per_step: np.ndarray
    time_to_collision: np.ndarray
    distance_to_road_edge: np.ndarray
    offroad_per_step: np.ndarray
    traffic_light_violation_per_step: np.ndarray


@dataclasses.dataclass(frozen=True)
class MapContext:
    """Map structures built once per scenario and shared by all rollouts."""

    road_edges: road_edge.SegmentTable
    lanes: traffic_lights.LaneTable | None


def map_context(scenario: ScenarioArrays) -> MapContext:
    return MapContext(road_edges=road_edge.build_segment_table(scenario.road_edges),
                      lanes=traffic_lights.build_lane_table(scenario.lanes, scenario.lane_ids))


def official_object_order(scene_ids, evaluated_ids) -> np.ndarray:
    """Evaluated ids, then the other ids in the order the official code visits them.

    The official code lists the non-evaluated agents by iterating a Python set
    difference; that order decides which values land in the trailing partial
    packet of vectorised ops (and ties between equidistant objects), so it is
    reproduced with the same set operations on the same integers.
    """
    others = set(int(i) for i in scene_ids) - set(int(i) for i in evaluated_ids)
    return np.array([int(i) for i in evaluated_ids] + list(others), dtype=np.int64)


def _composite(scenario: ScenarioArrays, order: np.ndarray, future_xyzh, future_valid) -> ObjectTrajectories:
    """History from the log, future from `future_xyzh`, sizes frozen at the current step.

    Args:
      order: int64 `(num_samples, num_objects)`, object ids per sample.
      future_xyzh: four float32 `(num_samples, num_objects, 80)`.
      future_valid: bool `(num_samples, num_objects, 80)`.
    """
    log = scenario.log
    rows = index_of_ids(log.object_id, order.reshape(-1)).reshape(order.shape)
    hist = slice(0, CURRENT_TIME_INDEX + 1)
    n_future = future_xyzh[0].shape[-1]

    def history(a):
        return a[rows][..., hist]

    def frozen(a):
        return np.concatenate([a[rows][..., hist], np.repeat(a[rows][..., CURRENT_TIME_INDEX:CURRENT_TIME_INDEX + 1],
                                                             n_future, axis=-1)], axis=-1)

    x, y, z, h = (np.concatenate([history(a), f.astype(_F)], axis=-1)
                  for a, f in zip((log.x, log.y, log.z, log.heading), future_xyzh))
    return ObjectTrajectories(
        x=x, y=y, z=z, heading=h, length=frozen(log.length), width=frozen(log.width),
        height=frozen(log.height), valid=np.concatenate([history(log.valid), future_valid], axis=-1),
        object_id=order, object_type=log.object_type[rows])


def log_trajectories(scenario: ScenarioArrays) -> ObjectTrajectories:
    """The logged future as if it were one rollout, with the log's validity."""
    log = scenario.log.take_ids(scenario.sim_agent_ids)
    order = official_object_order(scenario.sim_agent_ids, scenario.evaluated_ids)[None]
    rows = index_of_ids(log.object_id, order[0])
    future = tuple(a[rows][None, :, FUTURE] for a in (log.x, log.y, log.z, log.heading))
    return _composite(scenario, order, future, log.valid[rows][None, :, FUTURE])


def simulated_trajectories(scenario: ScenarioArrays, rollouts: RolloutArrays) -> ObjectTrajectories:
    """Each rollout's future after the logged history, every future step valid."""
    orders = np.stack([official_object_order(ids, scenario.evaluated_ids) for ids in rollouts.object_id])
    cols = np.stack([index_of_ids(ids, order) for ids, order in zip(rollouts.object_id, orders)])
    if (cols == cols[0]).all():  # usually every rollout lists the agents in the same order
        in_order = (cols[0] == np.arange(cols.shape[1])).all()
        take = lambda a: a if in_order else a[:, cols[0]]
    else:
        take = lambda a: np.take_along_axis(a, cols[..., None], axis=1)
    future = tuple(take(a) for a in (rollouts.x, rollouts.y, rollouts.z, rollouts.heading))
    return _composite(scenario, orders, future, np.ones(future[0].shape, dtype=bool))


def _box_corners_3d(traj: ObjectTrajectories, cos_h, sin_h, objects: slice, steps: slice):
    """Bottom corners, float32 `(..., objects, steps, 4, 3)`."""
    pick = lambda a: a[..., objects, steps]
    cx, cy = box_geometry.box_corners_xy(pick(traj.x), pick(traj.y), pick(traj.length),
                                         pick(traj.width), cos_h[..., objects, :], sin_h[..., objects, :])
    cz = np.broadcast_to((pick(traj.z) + (-pick(traj.height) * _F(0.5)))[..., None], cx.shape)
    return np.stack([cx, cy, cz], axis=-1)


def compute_metric_features(scenario: ScenarioArrays, traj: ObjectTrajectories,
                            context: MapContext, feature_valid: np.ndarray) -> MetricFeatures:
    """Features of the evaluated objects for every sample of `traj`.

    Args:
      traj: composite trajectories `(num_samples, num_objects, 91)` in official order.
      feature_valid: bool `(num_samples, num_evaluated, 91)`, the validity
        reported with the features (the log's for the log, the trajectories'
        for rollouts).
    """
    n_eval = len(scenario.evaluated_ids)
    e = slice(0, n_eval)
    dt = STEP_SECONDS
    speed, accel, ang_speed, ang_accel = kinematics.kinematic_features(
        traj.x[:, e], traj.y[:, e], traj.z[:, e], traj.heading[:, e], dt)

    cos_h, sin_h = box_geometry.heading_cos_sin(traj.heading, FUTURE)
    future = lambda a: a[..., FUTURE]
    nearest = interaction.distance_to_nearest_object(
        future(traj.x), future(traj.y), future(traj.length), future(traj.width),
        cos_h, sin_h, future(traj.valid), n_eval)
    ttc = interaction.time_to_collision(traj.x, traj.y, traj.length, traj.width, traj.heading,
                                        traj.valid, n_eval, dt, FUTURE)
    corners = _box_corners_3d(traj, cos_h, sin_h, e, FUTURE)
    edge = road_edge.distance_to_road_edge(corners, future(traj.valid[:, e]), context.road_edges)
    lights_from = CURRENT_TIME_INDEX  # a crossing at the first future step starts at "now"
    signals = scenario.signals
    red = traffic_lights.red_light_violation(
        traj.x[:, e, lights_from:], traj.y[:, e, lights_from:], traj.valid[:, e, lights_from:],
        context.lanes, None if signals is None else _signals_from(signals, lights_from))[..., 1:]

    ade = average_displacement_error(scenario, traj)
    return MetricFeatures(
        object_id=scenario.evaluated_ids,
        object_type=traj.object_type[:, e],
        valid=feature_valid[..., FUTURE],
        average_displacement_error=ade,
        linear_speed=future(speed), linear_acceleration=future(accel),
        angular_speed=future(ang_speed), angular_acceleration=future(ang_accel),
        distance_to_nearest_object=nearest,
        collision_per_step=nearest < _F(interaction.COLLISION_DISTANCE_THRESHOLD),
        time_to_collision=ttc,
        distance_to_road_edge=edge,
        offroad_per_step=edge > _F(road_edge.OFFROAD_DISTANCE_THRESHOLD),
        traffic_light_violation_per_step=red)


def average_displacement_error(scenario: ScenarioArrays, traj: ObjectTrajectories) -> np.ndarray:
    """Mean 3D distance to the log over the log's valid steps, float32 `(num_samples, num_evaluated)`."""
    e = slice(0, len(scenario.evaluated_ids))
    log_e = scenario.log.take_ids(scenario.evaluated_ids)
    dx = traj.x[:, e] - log_e.x
    dy = traj.y[:, e] - log_e.y
    dz = traj.z[:, e] - log_e.z
    displacement = np.sqrt(dx * dx + dy * dy + dz * dz)
    return (np.where(log_e.valid, displacement, _F(0)).sum(axis=-1, dtype=_F)
            / log_e.valid.sum(axis=-1).astype(_F))


def _signals_from(signals, start: int):
    return dataclasses.replace(signals, state=signals.state[start:], stop_point=signals.stop_point[start:])


def _stack_samples(a: ObjectTrajectories, b: ObjectTrajectories) -> ObjectTrajectories:
    """The samples of `a` followed by those of `b` (same number of objects)."""
    return ObjectTrajectories(**{f.name: np.concatenate([getattr(a, f.name), getattr(b, f.name)])
                                 for f in dataclasses.fields(ObjectTrajectories)})


def _split_samples(features: MetricFeatures, first: int) -> tuple[MetricFeatures, MetricFeatures]:
    """(the first `first` samples, the others)."""
    def part(rows):
        return MetricFeatures(**{f.name: getattr(features, f.name) if f.name == "object_id"
                                 else getattr(features, f.name)[rows] for f in dataclasses.fields(MetricFeatures)})
    return part(slice(0, first)), part(slice(first, None))


def scenario_features(scenario: ScenarioArrays, rollouts: RolloutArrays,
                      context: MapContext | None = None) -> tuple[MetricFeatures, MetricFeatures]:
    """(log features with one sample, simulated features with one sample per rollout).

    The log is computed as one more sample beside the rollouts: every kernel
    treats samples independently, and one call shares the map searches.
    """
    context = context or map_context(scenario)
    log_traj = log_trajectories(scenario)
    sim_traj = simulated_trajectories(scenario, rollouts)
    n_eval = len(scenario.evaluated_ids)
    both = _stack_samples(log_traj, sim_traj)
    feature_valid = np.concatenate([log_traj.valid[:, :n_eval], sim_traj.valid[:, :n_eval]])
    return _split_samples(compute_metric_features(scenario, both, context, feature_valid), 1)
