"""A `Scenario` message as columnar arrays: logged boxes, map polylines, signals."""
from __future__ import annotations

import dataclasses

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.trajectories import ObjectTrajectories
from wosac_eval.parse.wire import record_runs
from wosac_eval.protos import map_pb2, scenario_pb2


@dataclasses.dataclass(frozen=True)
class TrafficSignals:
    """Traffic-signal states per step, one column per signalled lane.

    Attributes:
      lane_id: int64 `(num_signals,)`, the lane each column describes.
      state: int32 `(num_steps, num_signals)`; 0 (unknown) where the lane has
        no state at that step.
      stop_point: float32 `(num_steps, num_signals, 2)`, xy of the stop point.
    """

    lane_id: np.ndarray
    state: np.ndarray
    stop_point: np.ndarray


@dataclasses.dataclass(frozen=True)
class ScenarioArrays:
    """Everything the metrics need from a `Scenario`.

    Attributes:
      scenario_id: the scenario's id.
      log: logged trajectories of every track, `(num_objects, 91)`, in track order.
      sim_agent_ids: ids of tracks valid at the current step (must be simulated),
        in track order, int64 `(num_sim_agents,)`.
      predicted_ids: sorted ids of the SDC and `tracks_to_predict`, int64
        `(num_predicted,)`: the objects the sim agents challenge evaluates.
      road_edges: road-edge polylines, each float32 `(num_points, 3)`.
      lane_ids: int64 `(num_lanes,)`, surface-street lanes only.
      lanes: the matching lane centre polylines, each float32 `(num_points, 3)`.
      signals: per-step traffic-signal states, or None when the scenario has
        no dynamic map states.
      sdc_id: the id of the self-driving car's track (-1 when unknown).
    """

    scenario_id: str
    log: ObjectTrajectories
    sim_agent_ids: np.ndarray
    predicted_ids: np.ndarray
    road_edges: tuple
    lane_ids: np.ndarray
    lanes: tuple
    signals: TrafficSignals | None
    sdc_id: int = -1

    def evaluated_ids(self, challenge="sim_agents") -> np.ndarray:
        """The objects a challenge evaluates, in the official order, int64 `(num_evaluated,)`."""
        return challenges.evaluated_ids(self.sim_agent_ids, self.predicted_ids, challenge)


def track_trajectories(scenario: scenario_pb2.Scenario) -> ObjectTrajectories:
    """Every track of the scenario, in track order, over all its steps (float32, as the official converter
    rounds); ValueError when the tracks have different numbers of states."""
    tracks = scenario.tracks
    num_steps = max((len(t.states) for t in tracks), default=0)
    if any(len(t.states) != num_steps for t in tracks):
        lengths = sorted({len(t.states) for t in tracks})
        raise ValueError(f"scenario {scenario.scenario_id}: tracks have different numbers "
                         f"of states {lengths}")
    shape = (len(tracks), num_steps)
    values = np.empty(shape + (len(_STATE_FIELDS),), np.float32)
    valid = np.empty(shape, bool)
    runs, _ = record_runs([t.SerializeToString() for t in tracks], 3, _STATE_LAYOUT, [num_steps] * len(tracks))
    for i, (track, run) in enumerate(zip(tracks, runs)):
        values[i], valid[i] = _track_states(track, num_steps, run)
    return ObjectTrajectories(
        x=values[..., 0], y=values[..., 1], z=values[..., 2], heading=values[..., 3],
        length=values[..., 4], width=values[..., 5], height=values[..., 6], valid=valid,
        object_id=np.array([t.id for t in tracks], dtype=np.int64),
        object_type=np.array([t.object_type for t in tracks], dtype=np.int32))


# ObjectState fields 2..11 and MapPoint fields 1..3 as laid out on the wire.
_STATE_LAYOUT = ((2, "d"), (3, "d"), (4, "d"), (5, "f"), (6, "f"), (7, "f"), (8, "f"), (9, "f"), (10, "f"),
                 (11, "b"))
_STATE_FIELDS = ("center_x", "center_y", "center_z", "heading", "length", "width", "height")
_STATE_COLUMNS = (0, 1, 2, 6, 3, 4, 5)  # _STATE_FIELDS in _STATE_LAYOUT
_POINT_LAYOUT = ((1, "d"), (2, "d"), (3, "d"))


def _track_states(track, num_steps: int, run: np.ndarray | None = None):
    """float32 `(num_steps, 7)` in `_STATE_FIELDS` order, bool `(num_steps,)` valid.

    float64 values are rounded once to float32, as the official converter does
    with Python floats. `run`: the states read from the wire (`record_runs`),
    or None to read the parsed fields.
    """
    if run is not None:
        return run[:, _STATE_COLUMNS].astype(np.float32), run[:, -1].astype(bool)
    states = track.states
    columns = [np.fromiter([getattr(st, f) for st in states], np.float64, num_steps) for f in _STATE_FIELDS]
    valid = np.fromiter([st.valid for st in states], bool, num_steps)
    return np.stack(columns, axis=-1).astype(np.float32), valid


def _polylines(parents, field_number: int) -> list:
    """float32 `(num_points, 3)` of a `repeated MapPoint` field, for each parent message."""
    point_lists = [parent.polyline for parent in parents]
    runs, _ = record_runs([parent.SerializeToString() for parent in parents], field_number, _POINT_LAYOUT,
                          [len(points) for points in point_lists])
    out = []
    for points, xyz in zip(point_lists, runs):
        if xyz is None:
            n = len(points)
            xyz = np.fromiter([c for p in points for c in (p.x, p.y, p.z)], np.float64, 3 * n).reshape(n, 3)
        out.append(xyz.astype(np.float32))
    return out


def _traffic_signals(scenario: scenario_pb2.Scenario) -> TrafficSignals | None:
    states = scenario.dynamic_map_states
    if not states:
        return None
    lanes = sorted({s.lane for step in states for s in step.lane_states})
    if not lanes:
        # A column of "unknown" states keeps shapes uniform; it never signals a stop.
        lanes = [-1]
    column = {lane: i for i, lane in enumerate(lanes)}
    state = np.zeros((len(states), len(lanes)), dtype=np.int32)
    stop = np.zeros((len(states), len(lanes), 2), dtype=np.float64)
    for t, step in enumerate(states):
        for s in step.lane_states:  # a later entry for the same lane wins, as officially
            state[t, column[s.lane]] = s.state
            stop[t, column[s.lane]] = (s.stop_point.x, s.stop_point.y)
    return TrafficSignals(lane_id=np.array(lanes, dtype=np.int64), state=state,
                          stop_point=stop.astype(np.float32))


def scenario_arrays(scenario: scenario_pb2.Scenario) -> ScenarioArrays:
    """Converts a parsed `Scenario` into `ScenarioArrays`."""
    surface = map_pb2.LaneCenter.TYPE_SURFACE_STREET
    edges, lane_ids, lanes = [], [], []
    for feature in scenario.map_features:
        kind = feature.WhichOneof("feature_data")
        if kind == "road_edge":
            edges.append(feature.road_edge)
        elif kind == "lane" and feature.lane.type == surface:
            lane_ids.append(feature.id)
            lanes.append(feature.lane)
    road_edges, lanes = _polylines(edges, 2), _polylines(lanes, 8)
    return ScenarioArrays(
        scenario_id=scenario.scenario_id,
        log=track_trajectories(scenario),
        sim_agent_ids=challenges.sim_agent_ids(scenario),
        predicted_ids=challenges.predicted_ids(scenario),
        road_edges=tuple(road_edges),
        lane_ids=np.array(lane_ids, dtype=np.int64),
        lanes=tuple(lanes),
        signals=_traffic_signals(scenario),
        sdc_id=int(scenario.tracks[scenario.sdc_track_index].id) if scenario.tracks else -1,
    )
