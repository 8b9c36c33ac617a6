"""A `Scenario` message as columnar arrays: logged boxes, map polylines, signals."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.trajectories import ObjectTrajectories
from wosac_eval.parse import wire_walks as walks
from wosac_eval.parse.errors import ParseError
from wosac_eval.parse.scenarios import ScenarioSource, parse_scenario, scenario_id_of
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
        in track order, int64 `(num_objects,)`.
      predicted_ids: sorted ids of the SDC and `tracks_to_predict`, int64
        `(num_evaluated,)`: the objects the sim agents challenge evaluates.
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

    def evaluated_ids(self, challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS) -> np.ndarray:
        """The objects a challenge evaluates, in the official order, int64 `(num_evaluated,)`."""
        return challenges.evaluated_ids(self.sim_agent_ids, self.predicted_ids, challenge)


def track_trajectories(scenario: scenario_pb2.Scenario) -> ObjectTrajectories:
    """Every track of the scenario, in track order, over all its steps (float32, as the official converter
    rounds); ValueError when the tracks have different numbers of states."""
    return _track_trajectories(scenario.scenario_id, *_with_whole(walks.message_bytes(scenario)))


def _with_whole(data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (data, *walks.whole(data))


# Scenario fields read from the wire: tracks 2, dynamic_map_states 7, map_features 8; Track: id 1,
# object_type 2, states 3; ObjectState fields 2..11 (`_STATE_LAYOUT`); MapFeature: id 1, lane 3 (LaneCenter:
# type 2, polyline 8), road_edge 5 (polyline 2); MapPoint x, y, z 1..3; DynamicMapState: lane_states 1
# (TrafficSignalLaneState: lane 1, state 2, stop_point 3).
# A layout lists (field number, wire type[, closed enum]) per field read.
_STATE_LAYOUT = (
    (2, walks.WIRE_FIXED64),
    (3, walks.WIRE_FIXED64),
    (4, walks.WIRE_FIXED64),
    (5, walks.WIRE_FIXED32),
    (6, walks.WIRE_FIXED32),
    (7, walks.WIRE_FIXED32),
    (8, walks.WIRE_FIXED32),
    (11, walks.WIRE_VARINT),
)
_STATE_FIELDS = ("center_x", "center_y", "center_z", "heading", "length", "width", "height")
_STATE_COLUMNS = (0, 1, 2, 6, 3, 4, 5)  # _STATE_FIELDS in _STATE_LAYOUT
_POINT_LAYOUT = ((1, walks.WIRE_FIXED64), (2, walks.WIRE_FIXED64), (3, walks.WIRE_FIXED64))


_OBJECT_TYPES = walks.enum_size(scenario_pb2.Track.ObjectType.DESCRIPTOR)
_LANE_TYPES = walks.enum_size(map_pb2.LaneCenter.LaneType.DESCRIPTOR)
_SIGNAL_STATES = walks.enum_size(map_pb2.TrafficSignalLaneState.State.DESCRIPTOR)


def _fields(data: Any, starts: Any, ends: Any, layout: Any) -> Any:
    """`walks.scalar_fields` of records with `layout`."""
    numbers = np.array([field[0] for field in layout], np.int64)
    wire_types = np.array([field[1] for field in layout], np.int64)
    enum_sizes = np.array([field[2] if len(field) > 2 else 0 for field in layout], np.int64)
    return walks.scalar_fields(data, starts, ends, numbers, wire_types, enum_sizes)


def _int32(varints: np.ndarray) -> np.ndarray:
    """int32 fields' varints (int64) as a parse reads them: their low 32 bits, as int64."""
    return varints.astype(np.int32).astype(np.int64)


def _current_validity(data: Any, track_start: Any, track_end: Any) -> np.ndarray:
    """Whether each track has a valid state at the current step (false for a track without one), bool
    `(num_objects,)`; each track's own states count, as in a parse."""
    state_start, state_end, owner = walks.message_spans(data, track_start, track_end, 3)
    first_of_track = np.searchsorted(owner, np.arange(len(track_start)))
    current = np.flatnonzero(np.arange(len(owner)) - first_of_track[owner] == challenges.CURRENT_TIME_INDEX)
    _, valid, _ = _fields(data, state_start[current], state_end[current], ((11, walks.WIRE_VARINT),))
    validity = np.zeros(len(track_start), bool)
    validity[owner[current]] = valid[:, 0] != 0
    return validity


def _track_trajectories(scenario_id: str, data: Any, starts: Any, ends: Any) -> ObjectTrajectories:
    track_start, track_end, _ = walks.message_spans(data, starts, ends, 2)
    _, header, _ = _fields(
        data, track_start, track_end, ((1, walks.WIRE_VARINT), (2, walks.WIRE_VARINT, _OBJECT_TYPES))
    )
    state_start, state_end, owner = walks.message_spans(data, track_start, track_end, 3)
    per_track = np.bincount(owner, minlength=len(track_start))
    num_steps = int(per_track.max(initial=0))
    if (per_track != num_steps).any():
        raise ValueError(
            f"scenario {scenario_id}: tracks have different numbers of states {sorted(set(per_track.tolist()))}"
        )
    real, integer, _ = _fields(data, state_start, state_end, _STATE_LAYOUT)
    # float64 values are rounded once to float32, as the official converter does with Python floats.
    values = real[:, _STATE_COLUMNS].astype(np.float32).reshape(len(track_start), num_steps, len(_STATE_FIELDS))
    return ObjectTrajectories(
        x=values[..., 0],
        y=values[..., 1],
        z=values[..., 2],
        heading=values[..., 3],
        length=values[..., 4],
        width=values[..., 5],
        height=values[..., 6],
        valid=(integer[:, -1] != 0).reshape(len(track_start), num_steps),
        object_id=_int32(header[:, 0]),
        object_type=header[:, 1].astype(np.int32),
    )


def _polylines(data: np.ndarray, starts: np.ndarray, ends: np.ndarray, field_number: int) -> list[np.ndarray]:
    """float32 `(num_points, 3)` of the `repeated MapPoint` field `field_number` of each parent span."""
    point_start, point_end, owner = walks.message_spans(data, starts, ends, field_number)
    xyz, _, _ = _fields(data, point_start, point_end, _POINT_LAYOUT)
    counts = np.bincount(owner, minlength=len(starts))
    return np.split(xyz.astype(np.float32), np.cumsum(counts)[:-1]) if len(starts) else []


def _map_polylines(data: Any, starts: Any, ends: Any) -> tuple[Any, Any, Any]:
    """(road-edge polylines, surface-street lane ids, their lane polylines), in map-feature order."""
    feature_start, feature_end, _ = walks.message_spans(data, starts, ends, 8)
    _, feature_id, _ = _fields(data, feature_start, feature_end, ((1, walks.WIRE_VARINT),))
    edge_start, edge_end, _ = walks.message_spans(data, feature_start, feature_end, 5)
    lane_start, lane_end, lane_feature = walks.message_spans(data, feature_start, feature_end, 3)
    _, lane_type, _ = _fields(data, lane_start, lane_end, ((2, walks.WIRE_VARINT, _LANE_TYPES),))
    surface = lane_type[:, 0] == map_pb2.LaneCenter.TYPE_SURFACE_STREET
    return (
        _polylines(data, edge_start, edge_end, 2),
        feature_id[lane_feature[surface], 0],
        _polylines(data, lane_start[surface], lane_end[surface], 8),
    )


_FEATURE_DATA = tuple(f.number for f in map_pb2.MapFeature.DESCRIPTOR.oneofs_by_name["feature_data"].fields)


def _merges_submessages(data: Any, starts: Any, ends: Any) -> bool:
    """Whether a map feature holds more than one of its (oneof) feature_data fields, or a signal's lane
    state more than one stop_point: a parse merges (or replaces) those, the walks would not."""
    feature_start, feature_end, _ = walks.message_spans(data, starts, ends, 8)
    if np.bincount(walks.message_spans(data, feature_start, feature_end, _FEATURE_DATA)[2], minlength=1).max() > 1:
        return True
    step_start, step_end, _ = walks.message_spans(data, starts, ends, 7)
    entry_start, entry_end, _ = walks.message_spans(data, step_start, step_end, 1)
    return np.bincount(walks.message_spans(data, entry_start, entry_end, 3)[2], minlength=1).max() > 1


def _traffic_signals(data: Any, starts: Any, ends: Any) -> TrafficSignals | None:
    step_start, step_end, _ = walks.message_spans(data, starts, ends, 7)
    if not len(step_start):
        return None
    entry_start, entry_end, step = walks.message_spans(data, step_start, step_end, 1)
    _, entry, _ = _fields(
        data, entry_start, entry_end, ((1, walks.WIRE_VARINT), (2, walks.WIRE_VARINT, _SIGNAL_STATES))
    )
    point_start, point_end, point_entry = walks.message_spans(data, entry_start, entry_end, 3)
    point_xy, _, _ = _fields(data, point_start, point_end, _POINT_LAYOUT[:2])
    stop_xy = np.zeros((len(entry_start), 2))
    stop_xy[point_entry] = point_xy  # one stop_point per entry at most (`_merges_submessages`)
    lanes, column = np.unique(entry[:, 0], return_inverse=True)
    if not len(lanes):
        # A column of "unknown" states keeps shapes uniform; it never signals a stop.
        lanes = np.array([-1])
    state = np.zeros((len(step_start), len(lanes)), dtype=np.int32)
    stop = np.zeros((len(step_start), len(lanes), 2), dtype=np.float64)
    # A later entry for the same lane at one step wins, as officially: keep each (step, lane)'s last entry.
    cell = step * len(lanes) + column
    last = len(cell) - 1 - np.unique(cell[::-1], return_index=True)[1]
    state.reshape(-1)[cell[last]] = entry[last, 1]
    stop.reshape(-1, 2)[cell[last]] = stop_xy[last]
    return TrafficSignals(lane_id=lanes.astype(np.int64), state=state, stop_point=stop.astype(np.float32))


def scenario_arrays(scenario: scenario_pb2.Scenario, wire_bytes: bytes | None = None) -> ScenarioArrays:
    """Converts a parsed `Scenario` into `ScenarioArrays` (its arrays read from its wire bytes at once).

    wire_bytes: the bytes `scenario` was parsed from, when at hand: read instead of serialising the
    message again (the walks read bytes as a parse does; bytes where a parse would merge repeated
    occurrences of a map feature or a stop point are read from the message's own serialisation).
    """
    data, starts, ends = _with_whole(walks.message_bytes(scenario if wire_bytes is None else wire_bytes))
    if wire_bytes is not None and _merges_submessages(data, starts, ends):
        data, starts, ends = _with_whole(walks.message_bytes(scenario))
    return _wire_arrays(scenario.scenario_id, data, starts, ends)


def record_arrays(record: bytes, source: ScenarioSource | str = "a Scenario record") -> ScenarioArrays:
    """`scenario_arrays` of a serialized `Scenario`, read from its bytes without a parse (what a scoring
    worker does: a parse of a real WOMD scene costs 2-6 ms, more than the walks).

    The walks read the fields the metrics use as a parse would; bytes they cannot read raise ParseError
    naming `source` (parts of the message no metric reads are skipped, not checked). A record where a
    parse would merge repeated occurrences is parsed after all (`scenario_arrays`' rule).
    """
    data, starts, ends = _with_whole(walks.message_bytes(record))
    try:
        if _merges_submessages(data, starts, ends):
            return scenario_arrays(parse_scenario(record, source))
        return _wire_arrays(scenario_id_of(record, source), data, starts, ends)
    except ParseError:
        raise
    except (ValueError, IndexError) as error:
        raise ParseError(f"{source}: {error}") from error


def record_sim_agent_ids(record: bytes, source: ScenarioSource | str = "a Scenario record") -> np.ndarray:
    """`challenges.sim_agent_ids` of a serialized `Scenario`, from its tracks' ids and current states
    alone (the validator's question of every scenario: which objects must a submission hold)."""
    data, starts, ends = _with_whole(walks.message_bytes(record))
    try:
        track_start, track_end, _ = walks.message_spans(data, starts, ends, 2)
        _, header, _ = _fields(data, track_start, track_end, ((1, walks.WIRE_VARINT),))
        return challenges.sim_agents_among(_int32(header[:, 0]), _current_validity(data, track_start, track_end))
    except ValueError as error:
        raise ParseError(f"{source}: not a valid Scenario message: {error}") from error


def _wire_arrays(scenario_id: str, data: Any, starts: Any, ends: Any) -> ScenarioArrays:
    log = _track_trajectories(scenario_id, data, starts, ends)
    # Every track has the log's steps (`_track_trajectories` refuses others): its current state is a column.
    current = challenges.CURRENT_TIME_INDEX
    valid_at_current = log.valid[:, current] if log.num_steps > current else np.zeros(log.num_objects, bool)
    _, sdc_index, _ = _fields(data, starts, ends, ((6, walks.WIRE_VARINT),))
    required_start, required_end, _ = walks.message_spans(data, starts, ends, 11)
    _, required_index, _ = _fields(data, required_start, required_end, ((1, walks.WIRE_VARINT),))
    sdc_track_index = int(_int32(sdc_index[:, 0])[0])
    road_edges, lane_ids, lanes = _map_polylines(data, starts, ends)
    return ScenarioArrays(
        scenario_id=scenario_id,
        log=log,
        sim_agent_ids=challenges.sim_agents_among(log.object_id, valid_at_current),
        predicted_ids=challenges.predicted_among(log.object_id, sdc_track_index, _int32(required_index[:, 0])),
        road_edges=tuple(road_edges),
        lane_ids=lane_ids.astype(np.int64),
        lanes=tuple(lanes),
        signals=_traffic_signals(data, starts, ends),
        sdc_id=int(log.object_id[sdc_track_index]) if len(log.object_id) else -1,
    )
