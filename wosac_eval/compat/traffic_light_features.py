"""`waymo_open_dataset.wdl_limited.sim_agents_metrics.traffic_light_features`, without TensorFlow.

    lanes = [f for f in scenario.map_features if f.HasField("lane") and f.lane.type == LaneType.TYPE_SURFACE_STREET]
    violations = traffic_light_features.compute_red_light_violation(
        center_x=x, center_y=y, valid=valid, evaluated_object_mask=mask,
        lane_polylines=[f.lane.polyline for f in lanes], lane_ids=[f.id for f in lanes],
        traffic_signals=[list(state.lane_states) for state in scenario.dynamic_map_states])

The violation is the library's own red-light kernel (`features.traffic_lights`, the one the metrics use):
bit for bit the official values. Polylines are lists of map points (`MapPoint`s) as officially, or arrays
`(num_points, 3)`; signals are `TrafficSignalLaneState` messages (or anything with their lane, state and
stop_point). Arrays `(num_objects, num_steps)` as officially, or with leading axes `(..., num_objects,
num_steps)`; anything implementing `__array__` or `__dlpack__`. Results: numpy arrays answering `.numpy()`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from wosac_eval.arrays.scenario import TrafficSignals
from wosac_eval.compat import _objects
from wosac_eval.compat._arrays import ArrayIn
from wosac_eval.features.search import PrunedSearch

# The official module's constant.
EXTREMELY_LARGE_DISTANCE = 1e10


def compute_red_light_violation(
    *,
    center_x: ArrayIn,
    center_y: ArrayIn,
    valid: ArrayIn,
    evaluated_object_mask: ArrayIn,
    lane_polylines: Sequence,
    lane_ids: Sequence[int],
    traffic_signals: Sequence[Sequence],
) -> np.ndarray:
    """Whether each evaluated object runs a red light at each step: it crosses the stop point of a signal that
    shows stop on the lane it is on.

    Args:
      center_x, center_y: float `(..., num_objects, num_steps)`.
      valid: bool `(..., num_objects, num_steps)`.
      evaluated_object_mask: bool `(num_objects,)`, the objects to score.
      lane_polylines: the lanes' centre lines, each a list of map points (or an array `(num_points, 3)`).
      lane_ids: the map feature id of each lane.
      traffic_signals: per step (`num_steps` of them), the signals' `TrafficSignalLaneState`s.
    Returns:
      bool `(..., num_evaluated, num_steps)`.

    Raises:
      ValueError: the official messages ('Missing lanes.', 'Missing traffic signals.', 'Inconsistent number
        of lane polylines and lane ids.', unequal shapes, signals for another number of steps); a validity or
        a mask that does not fit the objects; lanes that all have fewer than two points.
    """
    if not lane_polylines:
        raise ValueError("Missing lanes.")
    if not traffic_signals:
        raise ValueError("Missing traffic signals.")
    if len(lane_polylines) != len(lane_ids):
        raise ValueError("Inconsistent number of lane polylines and lane ids.")
    objects = _objects.read_objects({"center_x": center_x, "center_y": center_y}, valid, evaluated_object_mask)
    signals = signal_states(traffic_signals)
    if signals.state.shape[0] != objects.num_steps:
        raise ValueError(
            f"Incompatible shapes: [{len(objects.evaluated)},{objects.num_steps},1] vs. "
            f"[1,{signals.state.shape[0]},{signals.state.shape[1]}] (traffic_signals has "
            f"{signals.state.shape[0]} steps, the objects {objects.num_steps})"
        )
    lanes = _objects.lane_table(_objects.polyline_arrays(lane_polylines), lane_ids)
    if lanes is None:
        raise ValueError("Missing lanes: every lane polyline has fewer than two points.")
    order = objects.evaluated_first()
    search = PrunedSearch(None, lanes, signals)  # type: ignore[arg-type]  # no road edges are searched
    found = _objects.context(objects.laid_out(order), len(objects.evaluated), search, {})
    with np.errstate(invalid="ignore", divide="ignore"):
        return objects.result(found["traffic_light_violation_per_step"])


def signal_states(traffic_signals: Sequence[Sequence]) -> TrafficSignals:
    """Per-step lists of signal states as the kernel's `TrafficSignals`: one column per signalled lane (a lane
    without a state at a step is unknown there, a later state of a lane at one step wins, as officially; a
    single unknown column when no step has a signal)."""
    steps = [list(states) for states in traffic_signals]
    lanes = sorted({int(s.lane) for states in steps for s in states}) or [-1]
    column = {lane: k for k, lane in enumerate(lanes)}
    state = np.zeros((len(steps), len(lanes)), np.int32)
    stop = np.zeros((len(steps), len(lanes), 2), np.float64)  # the official float64 array, then float32
    for t, states in enumerate(steps):
        for s in states:
            state[t, column[int(s.lane)]] = s.state
            stop[t, column[int(s.lane)]] = (s.stop_point.x, s.stop_point.y)
    return TrafficSignals(lane_id=np.array(lanes, np.int64), state=state, stop_point=stop.astype(np.float32))
