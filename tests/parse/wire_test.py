"""Tests of reading repeated submessages straight from the wire, against the parsed fields."""
import numpy as np

from wosac_eval.arrays import scenario as scenario_module
from wosac_eval.parse.wire import field_spans, record_run, record_runs
from wosac_eval.protos import map_pb2, scenario_pb2

POINT = ((1, "d"), (2, "d"), (3, "d"))


def lane_with_points(points, **fields):
    lane = map_pb2.LaneCenter(**fields)
    for x, y, z in points:
        lane.polyline.add(x=x, y=y, z=z)
    return lane


def test_points_after_and_before_other_fields():
    pts = [(1.5, -2.25, 0.1), (1e6 + 0.3, -7e5, 12.0), (0.0, 0.0, 0.0)]
    lane = lane_with_points(pts, speed_limit_mph=25.0, type=2, interpolating=True,
                            entry_lanes=[5, 6], exit_lanes=[7])
    lane.left_boundaries.add(lane_start_index=0, lane_end_index=2, boundary_feature_id=9, boundary_type=1)
    run = record_run(lane.SerializeToString(), 8, POINT, len(pts))
    np.testing.assert_array_equal(run, np.array(pts))


def test_road_edge_with_and_without_type():
    pts = [(3.0, 4.0, 5.0), (6.0, 7.0, 8.0)]
    for edge in (map_pb2.RoadEdge(type=1), map_pb2.RoadEdge()):
        for p in pts:
            edge.polyline.add(x=p[0], y=p[1], z=p[2])
        np.testing.assert_array_equal(record_run(edge.SerializeToString(), 2, POINT, 2), pts)


def test_a_missing_coordinate_reads_as_its_default():
    lane = lane_with_points([(1.0, 2.0, 3.0), (4.0, 5.0, 6.0)])
    lane.polyline.add(x=1.0, y=2.0)  # z unset: a shorter record
    lane.polyline.add(y=7.5)
    lane.polyline.add(x=8.0, y=9.0, z=10.0)
    expected = [[p.x, p.y, p.z] for p in lane.polyline]
    np.testing.assert_array_equal(record_run(lane.SerializeToString(), 8, POINT, 5), expected)
    assert expected[2][2] == 0 and expected[3][0] == 0


def test_an_unknown_extra_field_is_irregular():
    lane = lane_with_points([(1.0, 2.0, 3.0)])
    point = map_pb2.MapPoint(x=1.0, y=2.0, z=3.0)
    data = point.SerializeToString() + bytes([(4 << 3) | 0, 1])  # field 4 = 1, unknown to MapPoint
    lane.polyline.add().MergeFromString(data)
    assert record_run(lane.SerializeToString(), 8, POINT, 2) is None
    np.testing.assert_array_equal(scenario_module._polylines([lane], 8)[0], [[1, 2, 3], [1, 2, 3]])


def make_track(num_steps=5, drop=None):
    track = scenario_pb2.Track(id=42, object_type=1)
    rng = np.random.default_rng(3)
    for t in range(num_steps):
        values = dict(center_x=rng.uniform(-9000, 9000), center_y=rng.uniform(-9000, 9000),
                      center_z=rng.uniform(-50, 50), length=4.5, width=1.9, height=1.6,
                      heading=float(rng.uniform(-3.2, 3.2)), velocity_x=1.0, velocity_y=-2.0, valid=t % 2 == 0)
        if t == drop:
            values.pop("center_y")
        track.states.add(**values)
    return track


def parsed_states(track):
    fields = scenario_module._STATE_FIELDS
    values = np.array([[getattr(s, f) for f in fields] for s in track.states], np.float64).astype(np.float32)
    return values, np.array([s.valid for s in track.states])


def states_from_the_wire(track):
    """The track's states read from the wire, checked against the parsed fields."""
    run = record_run(track.SerializeToString(), 3, scenario_module._STATE_LAYOUT, len(track.states))
    assert run is not None
    values, valid = scenario_module._track_states(track, len(track.states), run)
    expected_values, expected_valid = parsed_states(track)
    np.testing.assert_array_equal(values, expected_values)
    np.testing.assert_array_equal(valid, expected_valid)
    return values, valid


def test_track_states_from_the_wire_equal_the_parsed_fields():
    _, valid = states_from_the_wire(make_track())
    assert not valid.all() and valid.any()


def test_states_without_some_fields_read_as_defaults():
    # WOMD writes invalid states with center_z and valid only.
    track = make_track(drop=2)
    invalid = track.states.add()
    invalid.center_z = -1.0
    invalid.valid = False
    values, _ = states_from_the_wire(track)
    assert values[2, 1] == 0  # the missing center_y reads as its default


def test_irregular_track_falls_back_to_the_parsed_fields():
    track = make_track()
    track.states[1].MergeFromString(bytes([(12 << 3) | 0, 1]))  # a field ObjectState does not know
    assert record_run(track.SerializeToString(), 3, scenario_module._STATE_LAYOUT, 5) is None
    values, valid = scenario_module._track_states(track, 5)
    expected_values, expected_valid = parsed_states(track)
    np.testing.assert_array_equal(values, expected_values)
    np.testing.assert_array_equal(valid, expected_valid)


def test_count_beyond_the_data_is_irregular():
    lane = lane_with_points([(1.0, 2.0, 3.0)])
    assert record_run(lane.SerializeToString(), 8, POINT, 2) is None


def test_many_parents_at_once_with_one_irregular():
    lanes = [lane_with_points([(i, i + 0.5, -i)] * (i + 1)) for i in range(4)]
    lanes[2].polyline[0].MergeFromString(bytes([(4 << 3) | 0, 1]))  # unknown field in one point
    lanes[3].polyline.add(x=3.0)  # a short record among full ones
    values, regular = record_runs([lane.SerializeToString() for lane in lanes], 8, POINT,
                                  [len(lane.polyline) for lane in lanes])
    assert regular.tolist() == [True, True, False, True]
    for lane, v in zip(lanes, values):
        if v is not None:
            np.testing.assert_array_equal(v, [[p.x, p.y, p.z] for p in lane.polyline])
    # The scenario reader gives the same points for every lane, irregular or not.
    for lane, xyz in zip(lanes, scenario_module._polylines(lanes, 8)):
        np.testing.assert_array_equal(xyz, np.array([[p.x, p.y, p.z] for p in lane.polyline], np.float32))


def test_field_spans_split_a_submission_like_a_parse():
    from wosac_eval.protos import sim_agents_submission_pb2 as pb
    submission = pb.SimAgentsChallengeSubmission(account_name="a", unique_method_name="m", authors=["x", "y"])
    for sid in ("s1", "s2", "s3"):
        rollouts = submission.scenario_rollouts.add(scenario_id=sid)
        scene = rollouts.joint_scenes.add()
        scene.simulated_trajectories.add(object_id=7, center_x=[1.0, 2.0], center_y=[0.5, 0.5],
                                         center_z=[0.0, 0.0], heading=[0.1, 0.2])
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
