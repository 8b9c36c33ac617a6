"""Tests of the synthetic scene generator: determinism, format, physical plausibility, scripted events."""

from __future__ import annotations

import functools
import sys

import numpy as np
import pytest

from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import map_pb2, scenario_pb2
from wosac_eval.sim import geometry as geo
from wosac_eval.sim import scenes
from wosac_eval.sim.logged_scenes import colliding_pairs
from wosac_eval.sim.scene_recipes import SCENE_KINDS

STOP = (map_pb2.TrafficSignalLaneState.LANE_STATE_STOP, map_pb2.TrafficSignalLaneState.LANE_STATE_ARROW_STOP)


@functools.lru_cache(maxsize=1)
def demo_set() -> tuple[scenario_pb2.Scenario, ...]:
    """One scene of every kind (the demo set)."""
    return tuple(scenes.generate_scenes(len(SCENE_KINDS), seed=0))


def by_kind(kind: str) -> scenario_pb2.Scenario:
    return next(s for s in demo_set() if s.scenario_id.endswith(kind.replace("_", "-")))


def track_arrays(track: scenario_pb2.Track):
    """(91,) arrays x, y, heading, vx, vy, valid and the box length, width of one track."""
    st = track.states
    x = np.array([s.center_x for s in st])
    y = np.array([s.center_y for s in st])
    h = np.array([s.heading for s in st])
    vx = np.array([s.velocity_x for s in st])
    vy = np.array([s.velocity_y for s in st])
    valid = np.array([s.valid for s in st])
    k = int(np.argmax(valid))
    return x, y, h, vx, vy, valid, st[k].length, st[k].width


def test_same_seed_gives_byte_identical_scenarios():
    a = scenes.generate_scenes(3, seed=7)
    b = scenes.generate_scenes(3, seed=7)
    assert [s.SerializeToString() for s in a] == [s.SerializeToString() for s in b]
    assert scenes.scenario_fingerprint(a) == scenes.scenario_fingerprint(b)


def test_different_seeds_give_different_scenarios():
    a = scenes.generate_scene(7, 0)
    b = scenes.generate_scene(8, 0)
    assert a.SerializeToString() != b.SerializeToString()
    assert a.scenario_id != b.scenario_id


def test_shards_parse_with_our_reader(tmp_path):
    paths = scenes.write_scenario_shards(list(demo_set()), tmp_path, num_shards=3)
    assert [p.name for p in paths] == [f"synthetic.tfrecord-0000{k}-of-00003" for k in range(3)]
    read = {s.scenario.scenario_id: s.scenario for s in iter_scenarios(tmp_path)}
    assert set(read) == {s.scenario_id for s in demo_set()}
    for original in demo_set():
        assert read[original.scenario_id].SerializeToString() == original.SerializeToString()


@pytest.mark.parametrize("kind", SCENE_KINDS)
def test_scene_has_the_structure_the_official_metrics_need(kind):
    sc = by_kind(kind)
    assert len(sc.timestamps_seconds) == 91 and sc.current_time_index == 10
    assert all(len(t.states) == 91 for t in sc.tracks)
    assert len({t.id for t in sc.tracks}) == len(sc.tracks)
    assert 10 <= len(sc.tracks) <= 80
    evaluated = [sc.sdc_track_index] + [r.track_index for r in sc.tracks_to_predict]
    assert len(set(evaluated)) == len(evaluated) >= 3
    assert sc.tracks[sc.sdc_track_index].object_type == scenario_pb2.Track.TYPE_VEHICLE
    assert all(sc.tracks[i].states[10].valid for i in evaluated)
    features = {f.id: f for f in sc.map_features}
    assert len(features) == len(sc.map_features), "map feature ids must be unique"
    kinds = [f.WhichOneof("feature_data") for f in sc.map_features]
    for needed in ("lane", "road_line", "road_edge", "crosswalk"):
        assert needed in kinds
    assert any(f.lane.type == map_pb2.LaneCenter.TYPE_SURFACE_STREET for f in sc.map_features if f.HasField("lane"))
    for f in sc.map_features:
        if f.HasField("lane"):
            assert all(
                e in features and features[e].HasField("lane") for e in [*f.lane.entry_lanes, *f.lane.exit_lanes]
            )
    # Stop bars (solid white road lines) cross the lanes where the signalised lanes start.
    bars = [
        np.array([(p.x, p.y) for p in f.road_line.polyline])
        for f in sc.map_features
        if f.HasField("road_line") and f.road_line.type == map_pb2.RoadLine.TYPE_SOLID_SINGLE_WHITE
    ]
    for ls in sc.dynamic_map_states[0].lane_states:
        start = np.array([ls.stop_point.x, ls.stop_point.y])
        assert min(np.linalg.norm(bar - start, axis=1).min() for bar in bars) < 0.5
    assert len(sc.dynamic_map_states) == 91
    for dms in sc.dynamic_map_states:
        assert dms.lane_states, "every step lists the signal states"
        for ls in dms.lane_states:
            lane = features[ls.lane].lane
            # WOMD convention: the stop point is the first vertex of the controlled lane.
            assert (ls.stop_point.x, ls.stop_point.y) == (lane.polyline[0].x, lane.polyline[0].y)
    valid = np.array([[s.valid for s in t.states] for t in sc.tracks])
    assert valid[:, 10].sum() >= 10, "enough sim agents"


def _sizes_ok(object_type: int, length: float, width: float) -> bool:
    if object_type == scenario_pb2.Track.TYPE_VEHICLE:
        return 3.5 <= length <= 13.0 and 1.6 <= width <= 2.7
    if object_type == scenario_pb2.Track.TYPE_PEDESTRIAN:
        return 0.3 <= length <= 1.2 and 0.3 <= width <= 1.2
    return 1.2 <= length <= 2.2 and 0.4 <= width <= 1.0


@pytest.mark.parametrize("kind", SCENE_KINDS)
def test_logged_motion_is_physically_plausible(kind):
    sc = by_kind(kind)
    scripted_crash = set(sc.objects_of_interest) if kind == "collision" else set()
    limits = {1: (25.0, 8.5), 2: (3.0, 4.0), 3: (9.0, 4.0)}  # max speed m/s, max |acceleration| m/s^2
    for index, track in enumerate(sc.tracks):
        x, y, h, vx, vy, valid, length, width = track_arrays(track)
        assert _sizes_ok(track.object_type, length, width), (track.id, length, width)
        max_speed, max_acc = limits[track.object_type]
        pair = valid[1:] & valid[:-1]
        speed = np.hypot(np.diff(x), np.diff(y)) / 0.1
        assert np.all(speed[pair] <= max_speed), (sc.scenario_id, track.id, speed[pair].max())
        # The logged velocity agrees with the motion (finite differences, mid-step).
        v_field = np.hypot(vx, vy)
        assert np.all(np.abs(speed[pair] - 0.5 * (v_field[1:] + v_field[:-1])[pair]) < 0.6)
        triple = valid[2:] & valid[1:-1] & valid[:-2]
        acc = np.diff(speed) / 0.1
        if index not in scripted_crash:
            assert np.all(np.abs(acc[triple]) <= max_acc), (sc.scenario_id, track.id, np.abs(acc[triple]).max())
        # Heading follows the direction of travel while moving, and never spins.
        moving = pair & (speed > 2.0)
        travel = np.arctan2(np.diff(y), np.diff(x))
        assert np.all(np.abs(geo.wrap_angle(travel - h[1:])[moving]) < 0.35)
        yaw_rate = np.abs(geo.wrap_angle(np.diff(h))) / 0.1
        assert np.all(yaw_rate[pair] < 1.5)
        assert np.all(np.abs(h[valid]) <= np.pi)


def _logged_collisions(sc: scenario_pb2.Scenario) -> set[tuple[int, int]]:
    arrays = [track_arrays(t) for t in sc.tracks]
    x = np.stack([a[0] for a in arrays])
    y = np.stack([a[1] for a in arrays])
    h = np.stack([a[2] for a in arrays])
    valid = np.stack([a[5] for a in arrays])
    length = np.array([a[6] for a in arrays])
    width = np.array([a[7] for a in arrays])
    return set(colliding_pairs(x, y, h, length, width, valid))


@pytest.mark.parametrize("kind", [k for k in SCENE_KINDS if k != "collision"])
def test_no_logged_collisions_unless_scripted(kind):
    assert _logged_collisions(by_kind(kind)) == set()


def test_collision_scene_logs_exactly_the_scripted_collision():
    sc = by_kind("collision")
    assert _logged_collisions(sc) == {tuple(sorted(sc.objects_of_interest))}
    evaluated = {sc.sdc_track_index, *(r.track_index for r in sc.tracks_to_predict)}
    assert set(sc.objects_of_interest) <= evaluated


def _signed_distance_to_edges(sc: scenario_pb2.Scenario, px: float, py: float) -> float:
    """Distance to the nearest road-edge segment, positive on its right (off the road)."""
    best, sign = np.inf, 1.0
    for f in sc.map_features:
        if not f.HasField("road_edge"):
            continue
        pts = np.array([(p.x, p.y) for p in f.road_edge.polyline])
        a, b = pts[:-1], pts[1:]
        ab = b - a
        t = np.clip(((np.array([px, py]) - a) * ab).sum(1) / (ab * ab).sum(1), 0, 1)
        closest = a + t[:, None] * ab
        d = np.hypot(px - closest[:, 0], py - closest[:, 1])
        k = int(np.argmin(d))
        if d[k] < best:
            cross = ab[k, 0] * (py - a[k, 1]) - ab[k, 1] * (px - a[k, 0])
            best, sign = d[k], (1.0 if cross < 0 else -1.0)
    return sign * best


def test_offroad_scene_vehicle_ends_beyond_the_road_edge_and_others_stay_on_it():
    sc = by_kind("offroad")
    (leaver,) = sc.objects_of_interest
    x, y, *_rest, valid, _, _ = track_arrays(sc.tracks[leaver])
    last = int(np.nonzero(valid)[0][-1])
    assert _signed_distance_to_edges(sc, x[last], y[last]) > 1.0
    assert _signed_distance_to_edges(sc, x[10], y[10]) < 0.0
    for i, track in enumerate(sc.tracks):
        if track.object_type == scenario_pb2.Track.TYPE_VEHICLE and i != leaver:
            tx, ty, *_r, tvalid, _, _ = track_arrays(track)
            steps = np.nonzero(tvalid)[0][::10]
            assert all(_signed_distance_to_edges(sc, tx[k], ty[k]) < 0 for k in steps), track.id


def test_red_light_scene_logs_a_vehicle_crossing_its_stop_point_on_red():
    sc = by_kind("red_light")
    (runner,) = sc.objects_of_interest
    x, y, *_ = track_arrays(sc.tracks[runner])
    crossed_on_red = False
    for t in range(1, 91):
        for ls in sc.dynamic_map_states[t].lane_states:
            if ls.state not in STOP:
                continue
            lane = next(f.lane for f in sc.map_features if f.id == ls.lane)
            p0, p1 = lane.polyline[0], lane.polyline[1]
            d = np.array([p1.x - p0.x, p1.y - p0.y])
            before = (x[t - 1] - p0.x) * d[0] + (y[t - 1] - p0.y) * d[1]
            after = (x[t] - p0.x) * d[0] + (y[t] - p0.y) * d[1]
            lateral = abs((x[t] - p0.x) * d[1] - (y[t] - p0.y) * d[0]) / np.linalg.norm(d)
            crossed_on_red |= before < 0 <= after and lateral < 2.0
    assert crossed_on_red


def test_large_coordinates_and_heading_wrap_scenes():
    far = by_kind("large_coordinates")
    xs = [s.center_x for t in far.tracks for s in t.states if s.valid]
    assert min(abs(x) for x in xs) > 7000.0
    wrap = by_kind("heading_wrap")
    crosses = 0
    for track in wrap.tracks:
        h = np.array([s.heading for s in track.states if s.valid])
        crosses += bool((h > 3.0).any() and (h < -3.0).any())
    assert crosses >= 2, "several tracks head due West with headings on both sides of +-pi"


def test_occlusion_scene_has_gaps_late_and_early_tracks():
    sc = by_kind("occlusion")
    valid = np.array([[s.valid for s in t.states] for t in sc.tracks])
    first = valid.argmax(axis=1)
    last = 90 - valid[:, ::-1].argmax(axis=1)
    gaps = [(~valid[i, first[i] : last[i] + 1]).any() for i in range(len(valid))]
    assert any(gaps), "a track with invalid steps between valid ones"
    assert (~valid[:, 10]).any(), "a track that is not a sim agent"
    assert (first > 10).any() or (last < 10).any()
    for state in (s for t in sc.tracks for s in t.states if not s.valid):
        assert not state.HasField("center_x"), "invalid states carry no values, as in WOMD"


def test_objects_are_mixed_types_with_plausible_sizes():
    types = [t.object_type for sc in demo_set() for t in sc.tracks]
    for object_type in (1, 2, 3):
        assert types.count(object_type) > 0
    assert types.count(1) > types.count(3)


@pytest.mark.parametrize("kind", SCENE_KINDS)
def test_other_seeds_are_plausible_and_collision_free_too(kind, monkeypatch):
    sc = scenes.generate_scene(1, SCENE_KINDS.index(kind))
    monkeypatch.setattr(sys.modules[__name__], "by_kind", lambda _kind: sc)
    test_scene_has_the_structure_the_official_metrics_need(kind)
    test_logged_motion_is_physically_plausible(kind)
    if kind == "collision":
        test_collision_scene_logs_exactly_the_scripted_collision()
    else:
        test_no_logged_collisions_unless_scripted(kind)
