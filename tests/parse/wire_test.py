"""Tests of reading messages straight from the wire (`parse.wire`, `parse.wire_walks`), against the parsed fields.

The arrays of a scenario and of its rollouts are read by compiled walks over the message's bytes;
every test compares them with what a protobuf parse gives, field by field, including the cases
a parse treats specially: fields in another order, unknown fields, a known field number with the
wrong wire type, closed-enum values out of range, unpacked repeated floats, negative ids.
"""

import numpy as np
import pytest

from wosac_eval import challenges
from wosac_eval.arrays import scenario as scenario_module
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.parse import wire, wire_walks as walks
from wosac_eval.parse.errors import ParseError
from wosac_eval.parse.wire import field_spans
from wosac_eval.protos import map_pb2, scenario_pb2, sim_agents_submission_pb2 as pb


def key(number, wire_type):
    return wire.varint((number << 3) | wire_type)


def reference_arrays(scenario):
    """What the parsed fields say: (track values float32 (tracks, steps, 7), valid, ids, types,
    road-edge polylines, surface lane ids, their polylines, signal (lanes, state, stop))."""
    fields = scenario_module._STATE_FIELDS
    values = (
        np.array([[[getattr(s, f) for f in fields] for s in t.states] for t in scenario.tracks], np.float64)
        .astype(np.float32)
        .reshape(len(scenario.tracks), -1, len(fields))
    )
    valid = np.array([[s.valid for s in t.states] for t in scenario.tracks], bool).reshape(values.shape[:2])
    edges, lane_ids, lanes = [], [], []
    for feature in scenario.map_features:
        kind = feature.WhichOneof("feature_data")
        points = lambda f: np.array([[p.x, p.y, p.z] for p in f.polyline], np.float64).reshape(-1, 3).astype(np.float32)
        if kind == "road_edge":
            edges.append(points(feature.road_edge))
        elif kind == "lane" and feature.lane.type == map_pb2.LaneCenter.TYPE_SURFACE_STREET:
            lane_ids.append(feature.id)
            lanes.append(points(feature.lane))
    signals = None
    if scenario.dynamic_map_states:
        ids = sorted({s.lane for step in scenario.dynamic_map_states for s in step.lane_states}) or [-1]
        state = np.zeros((len(scenario.dynamic_map_states), len(ids)), np.int32)
        stop = np.zeros(state.shape + (2,), np.float64)
        for t, step in enumerate(scenario.dynamic_map_states):
            for s in step.lane_states:
                state[t, ids.index(s.lane)] = s.state
                stop[t, ids.index(s.lane)] = (s.stop_point.x, s.stop_point.y)
        signals = (np.array(ids), state, stop.astype(np.float32))
    return (
        values,
        valid,
        np.array([t.id for t in scenario.tracks]),
        np.array([t.object_type for t in scenario.tracks]),
        edges,
        np.array(lane_ids, np.int64),
        lanes,
        signals,
    )


def assert_reads_like_a_parse(scenario):
    """scenario_arrays of the message equal the parsed fields, bit for bit."""
    arrays = scenario_module.scenario_arrays(scenario)
    values, valid, ids, types, edges, lane_ids, lanes, signals = reference_arrays(scenario)
    log = arrays.log
    got = np.stack([getattr(log, f) for f in ("x", "y", "z", "heading", "length", "width", "height")], axis=-1)
    np.testing.assert_array_equal(got, values)
    np.testing.assert_array_equal(log.valid, valid)
    np.testing.assert_array_equal(log.object_id, ids)
    np.testing.assert_array_equal(log.object_type, types)
    assert len(arrays.road_edges) == len(edges) and len(arrays.lanes) == len(lanes)
    for a, b in zip(arrays.road_edges + arrays.lanes, edges + lanes):
        assert a.dtype == np.float32
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(arrays.lane_ids, lane_ids)
    if signals is None:
        assert arrays.signals is None
    else:
        for a, b in zip((arrays.signals.lane_id, arrays.signals.state, arrays.signals.stop_point), signals):
            np.testing.assert_array_equal(a, b)
    # The objects to simulate and to evaluate, as the parsed message names them.
    assert arrays.scenario_id == scenario.scenario_id
    for got, expected in (
        (arrays.sim_agent_ids, challenges.sim_agent_ids(scenario)),
        (arrays.predicted_ids, challenges.predicted_ids(scenario)),
    ):
        assert got.dtype == expected.dtype == np.int64
        np.testing.assert_array_equal(got, expected)
    assert arrays.sdc_id == scenario.tracks[scenario.sdc_track_index].id
    return arrays


def assert_record_reads_like_a_parse(record: bytes):
    """`record_arrays` and `record_sim_agent_ids` of serialized bytes equal what the parsed message gives."""
    parsed = scenario_pb2.Scenario.FromString(record)
    expected = assert_reads_like_a_parse(parsed)
    got = scenario_module.record_arrays(record)
    assert_same_arrays(got, expected)
    np.testing.assert_array_equal(scenario_module.record_sim_agent_ids(record), challenges.sim_agent_ids(parsed))
    return got


def assert_same_arrays(a, b):
    import dataclasses

    if dataclasses.is_dataclass(a):
        assert type(a) is type(b)
        for field in dataclasses.fields(a):
            assert_same_arrays(getattr(a, field.name), getattr(b, field.name))
    elif isinstance(a, tuple):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_same_arrays(x, y)
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)
    else:
        assert a == b


def random_scenario(seed: int, steps: int = 3):
    """A small scenario with every kind of content the reader looks at, some fields left unset."""
    rng = np.random.default_rng(seed)
    scenario = scenario_pb2.Scenario(scenario_id=f"s{seed}", current_time_index=1, sdc_track_index=0)
    scenario.timestamps_seconds.extend(0.1 * np.arange(steps))
    for i in range(4):
        track = scenario.tracks.add(
            id=int(rng.integers(-(2**31), 2**31)) if i == 3 else i + 1, object_type=int(rng.integers(0, 5))
        )
        for t in range(steps):
            values = dict(
                center_x=rng.uniform(-9e3, 9e3),
                center_y=rng.uniform(-9e3, 9e3),
                center_z=rng.normal(),
                length=4.5,
                width=float(rng.uniform(1, 3)),
                height=1.6,
                heading=float(rng.uniform(-4, 4)),
                velocity_x=1.0,
                valid=bool(rng.integers(0, 2)),
            )
            for name in list(values):
                if rng.random() < 0.2:
                    del values[name]
            track.states.add(**values)
    scenario.tracks_to_predict.add(track_index=int(rng.integers(-4, 4)))
    for f in range(6):
        feature = scenario.map_features.add(id=int(rng.integers(0, 2**40)))
        points = [dict(x=rng.normal() * 1e3, y=rng.normal() * 1e3, z=rng.normal()) for _ in range(rng.integers(0, 5))]
        if f % 3 == 0:
            feature.road_edge.type = 1
            feature.road_edge.polyline.extend(map_pb2.MapPoint(**p) for p in points)
        elif f % 3 == 1:
            feature.lane.type = int(rng.integers(0, 4))
            feature.lane.speed_limit_mph = 25.0
            feature.lane.entry_lanes.extend([1, 2])
            feature.lane.polyline.extend(map_pb2.MapPoint(**p) for p in points)
        else:
            feature.crosswalk.polygon.extend(map_pb2.MapPoint(**p) for p in points)
    for t in range(steps):
        step = scenario.dynamic_map_states.add()
        for lane in rng.integers(0, 4, size=3):
            entry = step.lane_states.add(lane=int(lane), state=int(rng.integers(0, 9)))
            if rng.random() < 0.7:
                entry.stop_point.x, entry.stop_point.y = rng.normal(size=2)
    return scenario


@pytest.mark.parametrize("seed", range(8))
def test_scenario_arrays_read_like_a_parse(seed):
    assert_reads_like_a_parse(random_scenario(seed))


@pytest.mark.parametrize("seed", range(6))
def test_a_record_reads_like_its_parse_without_one(seed):
    """What a scoring worker reads (`record_arrays`, a record's bytes, no parse) and what the validator
    asks of every scenario (`record_sim_agent_ids`); with 12 steps, so that a current step exists."""
    assert_record_reads_like_a_parse(random_scenario(seed, steps=12).SerializeToString())


def test_a_real_womd_scene_reads_like_its_parse():
    from support.submissions import SCENARIO_FILES, load_scenario

    for scenario_id in SCENARIO_FILES:
        arrays = assert_record_reads_like_a_parse(load_scenario(scenario_id).SerializeToString())
        assert len(arrays.sim_agent_ids) > 0 and len(arrays.predicted_ids) > 0


def test_track_ids_and_indices_as_a_parse_reads_int32_fields():
    """Encodings a parse accepts and a serializer never writes: an int32 id or index as a 5-byte varint
    (a parse keeps its low 32 bits), the SDC's index given twice (the last wins) and negative (from the end),
    tracks of different lengths (the validator's ids count each track's own states)."""
    scenario = random_scenario(7, steps=12)
    for track in scenario.tracks:
        track.states[10].valid = True
    raw = scenario.SerializeToString()
    five_byte_minus_two = b"\xfe\xff\xff\xff\x0f"
    track = scenario_pb2.Track(object_type=1)
    for _ in range(12):
        track.states.add(center_x=1.0, valid=True)
    odd_track = key(1, 0) + five_byte_minus_two + track.SerializeToString()
    required = key(1, 0) + five_byte_minus_two
    raw += key(2, 2) + wire.varint(len(odd_track)) + odd_track
    raw += key(11, 2) + wire.varint(len(required)) + required
    raw += key(6, 0) + b"\x01" + key(6, 0) + wire.varint((1 << 64) - 1)  # sdc_track_index 1, then -1
    parsed = scenario_pb2.Scenario.FromString(raw)
    assert (
        parsed.tracks[-1].id == -2 and parsed.sdc_track_index == -1 and parsed.tracks_to_predict[-1].track_index == -2
    )
    arrays = assert_record_reads_like_a_parse(raw)
    assert -2 in arrays.sim_agent_ids and arrays.sdc_id == -2

    short = scenario_pb2.Scenario()
    short.CopyFrom(parsed)
    del short.tracks[0].states[5:]  # a track without a current step: not a sim agent
    raw = short.SerializeToString()
    assert scenario_module.record_sim_agent_ids(raw).tolist() == challenges.sim_agent_ids(short).tolist()
    assert short.tracks[0].id not in scenario_module.record_sim_agent_ids(raw)
    with pytest.raises(ParseError, match="here: scenario s7: tracks have different numbers of states"):
        scenario_module.record_arrays(raw, "here")


def test_a_record_naming_a_track_it_does_not_hold_is_refused_as_its_parse_is():
    scenario = random_scenario(2, steps=12)
    scenario.tracks_to_predict.add(track_index=4)
    with pytest.raises(IndexError, match="a tracks_to_predict track_index 4 is not the index of a track"):
        challenges.predicted_ids(scenario)
    with pytest.raises(ParseError, match="shard-3 @ 80: a tracks_to_predict track_index 4 is not the index"):
        scenario_module.record_arrays(scenario.SerializeToString(), "shard-3 @ 80")


@pytest.mark.parametrize("bad", [b"\x12\x05abc", b"\x12\x02\x1a\x09", b"\x2a\x02\xff\xfe"])
def test_a_malformed_record_is_refused_naming_its_source(bad):
    with pytest.raises(ParseError, match="^shard-1 @ 0: "):
        scenario_module.record_arrays(bad, "shard-1 @ 0")
    if bad.startswith(b"\x12"):  # the tracks: what the validator reads
        with pytest.raises(ParseError, match="^shard-1 @ 0: not a valid Scenario message"):
            scenario_module.record_sim_agent_ids(bad, "shard-1 @ 0")


def test_unknown_fields_wrong_wire_types_and_closed_enums_read_as_a_parse_reads_them():
    scenario = random_scenario(0)
    extra = (
        key(12, 0)
        + b"\x01"  # a field ObjectState does not know
        + key(2, 0)
        + b"\x05"  # center_x (a double) as a varint: unknown
        + key(5, 1)
        + np.float64(3.0).tobytes()
    )  # length (a float) as a double: unknown
    scenario.tracks[1].states[1].MergeFromString(extra)
    scenario.map_features[0].road_edge.polyline[0].MergeFromString(key(4, 0) + b"\x01")
    scenario.tracks[2].MergeFromString(key(2, 0) + b"\x63")  # object_type 99: out of the enum, ignored
    scenario.dynamic_map_states[0].lane_states[0].MergeFromString(key(2, 0) + b"\x63")  # state 99
    scenario.map_features[1].lane.MergeFromString(key(2, 0) + b"\x09")  # lane type 9
    parsed = scenario_pb2.Scenario.FromString(scenario.SerializeToString())
    assert parsed.tracks[2].object_type == scenario.tracks[2].object_type < 5
    assert_reads_like_a_parse(parsed)


def test_states_of_different_counts_are_refused_by_name():
    scenario = random_scenario(1)
    scenario.tracks[2].states.add(center_x=1.0)
    with pytest.raises(ValueError, match="s1: tracks have different numbers of states \\[3, 4\\]"):
        scenario_module.scenario_arrays(scenario)


def test_a_scenario_without_map_or_signals():
    scenario = scenario_pb2.Scenario(scenario_id="empty")
    scenario.tracks.add(id=1).states.add(center_x=1.0, valid=True)
    arrays = assert_reads_like_a_parse(scenario)
    assert arrays.road_edges == () and arrays.lanes == () and arrays.signals is None


def trajectory(rng, steps, **fields):
    values = {
        name: rng.normal(size=steps).astype(np.float32).tolist()
        for name in ("center_x", "center_y", "center_z", "heading", "length", "width", "height")
    }
    values.update(fields)
    return pb.SimulatedTrajectory(**values)


def test_float_fields_packed_and_unpacked_with_counts_and_flags():
    rng = np.random.default_rng(4)
    t = trajectory(rng, 3, object_id=-7, object_type=2, length=[1.0, -2.0, float("nan")])
    raw = t.SerializeToString()
    # center_y once more, unpacked (one fixed32 value per field): a parse appends it.
    raw += key(3, 5) + np.float32(0.25).tobytes() + key(3, 5) + np.float32(np.inf).tobytes()
    parsed = pb.SimulatedTrajectory.FromString(raw)
    data = np.frombuffer(raw, np.uint8)
    fields = ("center_x", "center_y", "length", "height")
    numbers = np.array([wire.TRAJECTORY_FIELD_NUMBERS[f] for f in fields])
    values, count, non_finite, non_positive = walks.float_fields(data, *walks.whole(data), numbers, 4)
    for j, f in enumerate(fields):
        expected = np.array(getattr(parsed, f), np.float32)
        assert count[0, j] == len(expected)
        np.testing.assert_array_equal(values[0, j, : len(expected)], expected[:4])
        assert non_finite[0, j] == (not np.isfinite(expected).all())
        assert non_positive[0, j] == bool((expected[np.isfinite(expected)] <= 0).any())
    assert count[0].tolist() == [3, 5, 3, 3]


def test_rollout_arrays_equal_the_parsed_fields():
    rng = np.random.default_rng(5)
    rollouts = pb.ScenarioRollouts(scenario_id="r")
    for _ in range(3):
        scene = rollouts.joint_scenes.add()
        for object_id in (5, -3, 2**31 - 1):
            scene.simulated_trajectories.append(trajectory(rng, 4, object_id=object_id, object_type=object_id % 5))
    rollouts.joint_scenes[1].simulated_trajectories[0].MergeFromString(key(10, 0) + b"\x63")  # type 99: ignored
    rollouts = pb.ScenarioRollouts.FromString(rollouts.SerializeToString())
    arrays = rollout_arrays(rollouts, "scenario_gen")
    for r, scene in enumerate(rollouts.joint_scenes):
        for a, t in enumerate(scene.simulated_trajectories):
            assert arrays.object_id[r, a] == t.object_id and arrays.object_type[r, a] == t.object_type
            for name, got in (
                ("center_x", arrays.x),
                ("heading", arrays.heading),
                ("length", arrays.length),
                ("width", arrays.width),
                ("height", arrays.height),
            ):
                np.testing.assert_array_equal(got[r, a], np.array(getattr(t, name), np.float32))


def test_rollouts_of_odd_shapes_are_refused_by_scene_and_field():
    rng = np.random.default_rng(6)
    rollouts = pb.ScenarioRollouts(scenario_id="odd")
    for _ in range(3):
        rollouts.joint_scenes.add().simulated_trajectories.extend(trajectory(rng, 4, object_id=i) for i in range(2))
    rollouts.joint_scenes[2].simulated_trajectories[1].center_z.append(0.0)
    with pytest.raises(ValueError, match="odd rollout 2: center_z lengths differ from 4"):
        rollout_arrays(rollouts)
    del rollouts.joint_scenes[2].simulated_trajectories[1].center_z[-1]
    rollouts.joint_scenes[1].simulated_trajectories[0].height.append(1.0)
    rollout_arrays(rollouts)  # sim agents: box sizes are not read
    with pytest.raises(ValueError, match="odd rollout 1: height lengths differ from 4; the official scorer"):
        rollout_arrays(rollouts, "scenario_gen")
    del rollouts.joint_scenes[1].simulated_trajectories[1]
    with pytest.raises(ValueError, match="odd rollout 1: 1 trajectories, rollout 0 has 2"):
        rollout_arrays(rollouts)


@pytest.mark.parametrize(
    "bad",
    [
        b"\x0a\x05abc",
        b"\x0b\x00",
        b"\x08",
        b"\x00\x01",
        b"\x0a\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff\x01",
        b"\x15\x00\x00",
    ],
)
def test_walks_refuse_malformed_bytes(bad):
    data = np.frombuffer(bad, np.uint8)
    with pytest.raises(ValueError, match="protobuf wire data"):
        walks.message_spans(data, *walks.whole(data), 1)


def test_field_spans_split_a_submission_like_a_parse():
    from wosac_eval.protos import sim_agents_submission_pb2 as pb

    submission = pb.SimAgentsChallengeSubmission(account_name="a", unique_method_name="m", authors=["x", "y"])
    for sid in ("s1", "s2", "s3"):
        rollouts = submission.scenario_rollouts.add(scenario_id=sid)
        scene = rollouts.joint_scenes.add()
        scene.simulated_trajectories.add(
            object_id=7, center_x=[1.0, 2.0], center_y=[0.5, 0.5], center_z=[0.0, 0.0], heading=[0.1, 0.2]
        )
    raw = submission.SerializeToString()
    spans = field_spans(raw, 1)
    assert [pb.ScenarioRollouts.FromString(raw[a:b]) for a, b in spans] == list(submission.scenario_rollouts)
    # The metadata strings are other fields of the same wire type.
    assert [raw[a:b].decode() for a, b in field_spans(raw, 3)] == ["a"]


def test_field_spans_reject_malformed_bytes():
    import pytest

    for bad in (b"\x0a\x05abc", b"\x0b\x00", b"\x08", b"\x00\x01", b"\x0a\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff\x01"):
        with pytest.raises(ValueError):
            field_spans(bad, 1)


def test_scenario_arrays_from_the_parsed_bytes_equal_those_from_the_message():
    """`scenario_arrays(scenario, wire_bytes)` reads the record's bytes; where a parse merges repeated
    occurrences of a map feature's data or of a stop point, it reads the message's own serialisation."""
    scenario = random_scenario(3)
    raw = scenario.SerializeToString()
    edge = map_pb2.MapFeature(id=77)
    edge.road_edge.polyline.add(x=1.0, y=2.0, z=3.0)
    more = map_pb2.RoadEdge()
    more.polyline.add(x=4.0, y=5.0, z=6.0)
    lane = map_pb2.LaneCenter(type=map_pb2.LaneCenter.TYPE_SURFACE_STREET)
    lane.polyline.add(x=7.0, y=8.0, z=9.0)
    twice = edge.SerializeToString() + key(5, 2) + wire.varint(more.ByteSize()) + more.SerializeToString()
    switched = edge.SerializeToString() + key(3, 2) + wire.varint(lane.ByteSize()) + lane.SerializeToString()
    stop = map_pb2.MapPoint(x=0.5)
    entry = map_pb2.TrafficSignalLaneState(lane=3, state=4, stop_point=map_pb2.MapPoint(y=2.5))
    merged_stop = entry.SerializeToString() + key(3, 2) + wire.varint(stop.ByteSize()) + stop.SerializeToString()
    step = key(1, 2) + wire.varint(len(merged_stop)) + merged_stop
    for extra in (
        b"",
        key(8, 2) + wire.varint(len(twice)) + twice,
        key(8, 2) + wire.varint(len(switched)) + switched,
        key(7, 2) + wire.varint(len(step)) + step,
    ):
        data = raw + extra
        parsed = scenario_pb2.Scenario.FromString(data)
        from_bytes = scenario_module.scenario_arrays(parsed, data)
        assert_reads_like_a_parse(parsed)
        expected = scenario_module.scenario_arrays(parsed)
        for a, b in zip(from_bytes.road_edges + from_bytes.lanes, expected.road_edges + expected.lanes):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(from_bytes.signals.stop_point, expected.signals.stop_point)
        np.testing.assert_array_equal(from_bytes.log.x, expected.log.x)
    assert parsed.dynamic_map_states[-1].lane_states[0].stop_point.x == 0.5
