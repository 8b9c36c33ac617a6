"""Criticality, SDC driving scores and realism per object type, on hand-built and demo scenes."""
from __future__ import annotations

import math

import numpy as np
import pytest

from wosac_eval.analysis.criticality_features import criticality_features
from wosac_eval.analysis.criticality_scores import (BehaviourHistogram, scenario_criticality, scene_criticality,
                                                   set_histogram, step_criticality, with_rarity)
from wosac_eval.arrays.messages import rollouts_from_arrays
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.protos import scenario_pb2
from wosac_eval.scoring.scenario import score_scenario
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import policy_rollouts

STEPS = 91
DT = 0.1


def straight_road_scene(tracks: list[dict], scenario_id: str = "hand-built") -> scenario_pb2.Scenario:
    """A 400 m straight road (edges at y = -6 and y = 6) with the given tracks; the first is the SDC.

    Each track: x, y (91 values), optional heading, type (1 vehicle, 2 pedestrian), length, width.
    """
    sc = scenario_pb2.Scenario(scenario_id=scenario_id, current_time_index=10, sdc_track_index=0)
    sc.timestamps_seconds.extend((np.arange(STEPS) * DT).round(6).tolist())
    # Road edges run with the road on their left (the official sign: positive off the road).
    for fid, y, xs in ((1, -6.0, np.linspace(-200.0, 200.0, 401)), (2, 6.0, np.linspace(200.0, -200.0, 401))):
        edge = sc.map_features.add(id=fid)
        edge.road_edge.type = 1
        for x in xs:
            edge.road_edge.polyline.add(x=float(x), y=y, z=0.0)
    for _ in range(STEPS):
        sc.dynamic_map_states.add()
    for k, spec in enumerate(tracks):
        x, y = np.asarray(spec["x"], float), np.asarray(spec["y"], float)
        vx, vy = np.gradient(x, DT), np.gradient(y, DT)
        heading = spec.get("heading", np.arctan2(vy, vx) if np.hypot(vx, vy).max() > 0.1 else np.zeros(STEPS))
        track = sc.tracks.add(id=100 + k, object_type=spec.get("type", 1))
        for t in range(STEPS):
            track.states.add(center_x=x[t], center_y=y[t], center_z=0.8, length=spec.get("length", 4.5),
                             width=spec.get("width", 2.0), height=1.6, heading=float(np.broadcast_to(heading, STEPS)[t]),
                             velocity_x=vx[t], velocity_y=vy[t], valid=True)
        if k:
            sc.tracks_to_predict.add(track_index=k)
    return sc


def cruise(x0: float, y: float, speed: float) -> dict:
    return {"x": x0 + speed * DT * np.arange(STEPS), "y": np.full(STEPS, y)}


def hard_brake(x0: float, y: float, speed: float, at_step: int, deceleration: float) -> dict:
    v = np.maximum(speed - deceleration * DT * np.clip(np.arange(STEPS) - at_step, 0, None), 0.0)
    x = x0 + np.concatenate([[0.0], np.cumsum(v[:-1] * DT)])
    return {"x": x, "y": np.full(STEPS, y)}


def scene_score(scenario) -> dict:
    """The scene's criticality rated against a histogram of itself (rarity then plays no part in a ranking)."""
    features = criticality_features(scenario_arrays(scenario))
    scene = scene_criticality(features)
    histogram = BehaviourHistogram()
    histogram.add(features.behaviour)
    return with_rarity(scene, histogram)


@pytest.mark.slow  # among the longest outside Ray, browser and JAX (--durations): the full run's
def test_a_hard_brake_is_more_critical_than_cruising():
    cruising = scene_score(straight_road_scene([cruise(-100, -3, 12.0), cruise(-60, 3, 12.0)]))
    braking = scene_score(straight_road_scene([hard_brake(-100, -3, 14.0, 40, 7.0), cruise(-60, 3, 12.0)]))
    assert braking["components"]["braking"] > 0.9 > 0.1 > cruising["components"]["braking"]
    assert braking["raw"]["braking"] == pytest.approx(7.0, abs=0.5)
    assert braking["score"] > cruising["score"] + 0.15
    assert 35 <= braking["peak_step"] <= 60  # the brake, not elsewhere


def test_a_near_miss_is_more_critical_than_free_flow():
    free = scene_score(straight_road_scene([cruise(-100, -3, 10.0), cruise(-20, 3, 10.0)]))
    # A car passes a stopped car in the next lane 0.3 m apart at 12 m/s.
    passing = straight_road_scene([cruise(-100, -3.0, 12.0), {"x": np.full(STEPS, -40.0), "y": np.full(STEPS, -0.7),
                                                              "heading": np.zeros(STEPS)}])
    near = scene_score(passing)
    # exp(-0.3 / 0.5) x 12 / (12 + 2) = 0.47; no collision course (parallel paths): no closing speed.
    assert near["components"]["near_miss"] > 0.4 > 0.01 > free["components"]["near_miss"]
    assert near["raw"]["closing_speed"] == 0.0 and near["raw"]["time_to_collision"] is None  # none: inf
    assert near["score"] > free["score"] + 0.1
    # A head-on course (closing at 24 m/s) has a short time to collision and a high closing speed.
    head_on = scene_score(straight_road_scene([cruise(-100, -3, 12.0),
                                               {"x": 100 - 12.0 * DT * np.arange(STEPS), "y": np.full(STEPS, -3.0)}]))
    assert head_on["raw"]["time_to_collision"] < 1.0 and head_on["raw"]["closing_speed"] > 20
    assert head_on["score"] > free["score"] + 0.25


def test_step_criticality_peaks_where_the_event_is():
    features = criticality_features(scenario_arrays(
        straight_road_scene([hard_brake(-100, -3, 14.0, 60, 7.0), cruise(-60, 3, 12.0)])))
    steps = step_criticality(features)
    assert steps.shape == (STEPS,) and np.all((steps >= 0) & (steps <= 0.85))
    assert steps[55:70].max() > 0.2 > steps[10:45].max()


def test_rarity_depends_on_the_set():
    calm = [scenario_criticality(scenario_arrays(straight_road_scene([cruise(-100, -3, 10.0 + k),
                                                                      cruise(-60, 3, 11.0)]))) for k in range(5)]
    brake = scenario_criticality(scenario_arrays(
        straight_road_scene([hard_brake(-100, -3, 14.0, 40, 7.0), cruise(-60, 3, 12.0)])))
    among_calm = with_rarity(brake, set_histogram(calm + [brake]))
    among_brakes = with_rarity(brake, set_histogram([brake] * 6))
    assert among_calm["components"]["rarity"] > among_brakes["components"]["rarity"]
    assert 0.0 <= among_brakes["components"]["rarity"] <= among_calm["components"]["rarity"] <= 1.0


@pytest.fixture(scope="module")
def demo_scenes():
    return scenes.generate_scenes(10, seed=0)


def test_demo_event_scenes_rank_above_dense_following(demo_scenes):
    kinds = {sc.scenario_id: sc.scenario_id.split("-", 3)[-1] for sc in demo_scenes}
    heuristic = {sc.scenario_id: scenario_criticality(scenario_arrays(sc)) for sc in demo_scenes}
    histogram = set_histogram(list(heuristic.values()))
    score = {sid: with_rarity(h, histogram)["score"] for sid, h in heuristic.items()}
    by_kind = {}
    for sid, value in score.items():
        by_kind.setdefault(kinds[sid], []).append(value)
    dense = max(by_kind["dense-following"])
    for kind in ("collision", "red-light", "offroad"):
        assert min(by_kind[kind]) > dense, (kind, by_kind)


def log_replay(scenario):
    """32 copies of the logged future of every sim agent (invalid logged steps held at the last valid state)."""
    arrays = scenario_arrays(scenario)
    log = arrays.log.take_ids(arrays.sim_agent_ids)
    columns = []
    for name in ("x", "y", "z", "heading"):
        values = np.asarray(getattr(log, name), np.float64).copy()
        for row, valid in zip(values, np.asarray(log.valid)):
            last = row[10]
            for t in range(11, STEPS):
                last = row[t] if valid[t] else last
                row[t] = last
        columns.append(np.broadcast_to(values[:, 11:], (32, *values[:, 11:].shape)))
    return rollouts_from_arrays(scenario.scenario_id, arrays.sim_agent_ids, *columns)


@pytest.mark.slow  # among the longest outside Ray, browser and JAX (--durations): the full run's
def test_log_replay_drives_better_than_constant_velocity(demo_scenes):
    replay, constant = [], []
    for scenario in demo_scenes:
        for rollouts, out in ((log_replay(scenario), replay),
                              (policy_rollouts(scenario, "constant_velocity"), constant)):
            row = score_scenario(scenario, rollouts, analysis=True)
            driving = row["driving"]
            assert set(driving) == {"score", "components"} and 0.0 <= driving["score"] <= 1.0
            out.append(driving["score"])
    assert np.mean(replay) > np.mean(constant) + 0.05
    # The logged SDC reaches its own route's end.
    row = score_scenario(demo_scenes[0], log_replay(demo_scenes[0]), analysis=True)
    assert row["driving"]["components"]["progress"] == pytest.approx(1.0, abs=1e-6)


def test_a_single_type_scene_has_the_overall_metrics_for_its_type():
    """With vehicles alone evaluated, the vehicle row repeats the scenario's own metrics."""
    scenario = straight_road_scene([cruise(-100, -3, 12.0), hard_brake(-80, -3, 12.0, 40, 3.0),
                                    cruise(-60, 3, 9.0), cruise(-20, 3, 9.5)])
    replay = log_replay(scenario)
    noise = np.random.default_rng(0).normal(0.0, 0.3, replay.x.shape).astype(np.float32)
    rollouts = rollouts_from_arrays(scenario.scenario_id, replay.object_id, replay.x + noise, replay.y - noise,
                                    replay.z, replay.heading)
    row = score_scenario(scenario, rollouts, analysis=True)
    assert list(row["by_object_type"]) == ["vehicle"]
    vehicle = row["by_object_type"]["vehicle"]
    assert vehicle["num_objects"] == 4
    for key, value in vehicle.items():
        if key != "num_objects":
            assert value == pytest.approx(row[key], abs=1e-6), key


def test_object_type_rows_split_the_objects(demo_scenes):
    scenario = demo_scenes[0]
    rollouts = policy_rollouts(scenario, "constant_velocity")
    sg = score_scenario(scenario, policy_rollouts(scenario, "log_replay_noise", challenge="scenario_gen"),
                        challenge="scenario_gen", analysis=True)
    log = scenario_arrays(scenario).log
    sim_agent_types = log.object_type[np.isin(log.object_id, scenario_arrays(scenario).sim_agent_ids)]
    counts = {name: int((sim_agent_types == code).sum()) for code, name in ((1, "vehicle"), (2, "pedestrian"),
                                                                            (3, "cyclist"))}
    assert {k: v["num_objects"] for k, v in sg["by_object_type"].items()} == {k: v for k, v in counts.items() if v}
    for values in sg["by_object_type"].values():
        for key, value in values.items():
            assert value is None or (math.isfinite(value) and value >= 0), key
    plain = score_scenario(scenario, rollouts)
    assert "criticality" not in plain and "driving" not in plain and "by_object_type" not in plain
