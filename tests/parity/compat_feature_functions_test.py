"""The official feature functions of `wosac_eval.compat`, called as the official `compute_metric_features` calls
them, give the library's per-step features and the official ones, bit for bit, on every golden case.

Each case's log and rollouts are laid out as the official code lays them out (all steps, the evaluated objects
first: `arrays.samples`, the library's batch) and passed with a leading samples axis; the map as the official
code reads it from the `Scenario` (road edges, surface-street lanes, per-step signal states).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from support import golden
from wosac_eval.arrays.samples import sample_batch
from wosac_eval.compat import (
    interaction_features,
    map_metric_features,
    traffic_light_features,
    trajectory_features,
)
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.protos import map_pb2

CASES = golden.all_cases()
_SURFACE = map_pb2.LaneCenter.LaneType.TYPE_SURFACE_STREET


@lru_cache(maxsize=4)
def _library(case_set, case):
    return scenario_features(*golden.inputs(case_set, case), challenge=case_set.challenge)


def _map(scenario):
    edges = [list(f.road_edge.polyline) for f in scenario.map_features if f.HasField("road_edge")]
    lanes = [f for f in scenario.map_features if f.HasField("lane") and f.lane.type == _SURFACE]
    signals = [list(state.lane_states) for state in scenario.dynamic_map_states]
    return edges, [list(f.lane.polyline) for f in lanes], [f.id for f in lanes], signals


def compat_features(case_set, case) -> dict:
    """The per-step features of the case's log and rollouts by the compat functions: `(samples, evaluated, steps)`."""
    scenario_arrays, rollouts = golden.inputs(case_set, case)
    batch = sample_batch(scenario_arrays, rollouts, case_set.challenge)
    t, e = batch.trajectories, batch.num_evaluated
    mask = np.arange(t.num_objects) < e
    boxes = {"center_x": t.x, "center_y": t.y, "length": t.length, "width": t.width, "heading": t.heading}
    full = {**boxes, "center_z": t.z, "height": t.height, "valid": t.valid, "evaluated_object_mask": mask}
    edges, lanes, lane_ids, signals = _map(golden.scenario(rollouts.scenario_id))
    out = dict(
        zip(
            ("linear_speed", "linear_acceleration", "angular_speed", "angular_acceleration"),
            trajectory_features.compute_kinematic_features(
                t.x[:, :e], t.y[:, :e], t.z[:, :e], t.heading[:, :e], seconds_per_step=0.1
            ),
        )
    )
    out["distance_to_nearest_object"] = interaction_features.compute_distance_to_nearest_object(**full)
    out["time_to_collision"] = interaction_features.compute_time_to_collision_with_object_in_front(
        **boxes, valid=t.valid, evaluated_object_mask=mask, seconds_per_step=0.1
    )
    out["distance_to_road_edge"] = map_metric_features.compute_distance_to_road_edge(**full, road_edge_polylines=edges)
    if lanes and signals:  # as officially: without either, no violation
        out["traffic_light_violation_per_step"] = traffic_light_features.compute_red_light_violation(
            center_x=t.x,
            center_y=t.y,
            valid=t.valid,
            evaluated_object_mask=mask,
            lane_polylines=lanes,
            lane_ids=lane_ids,
            traffic_signals=signals,
        )
    out["collision_per_step"] = out["distance_to_nearest_object"] < interaction_features.COLLISION_DISTANCE_THRESHOLD
    out["offroad_per_step"] = out["distance_to_road_edge"] > map_metric_features.OFFROAD_DISTANCE_THRESHOLD
    reported = slice(batch.spec.first_simulated_step, None)
    return {name: np.asarray(value)[..., reported] for name, value in out.items()}


@pytest.mark.parametrize("case_set, case", CASES)
def test_feature_functions_are_the_library_and_the_official_features(case_set, case):
    golden.skip_if_absent(case_set, case)
    ours = compat_features(case_set, case)
    log, sim = _library(case_set, case)
    expected = golden.expected_features(case_set, case)
    for name, value in ours.items():
        library = np.concatenate([log.feature(name), sim.feature(name)])
        assert value.dtype == library.dtype, name
        np.testing.assert_array_equal(value, library, err_msg=f"{case}: {name} (the library)")
        official = np.concatenate([expected["log_" + name], expected["sim_" + name]])
        np.testing.assert_array_equal(value, official, err_msg=f"{case}: {name} (official)")
    assert len(ours) >= 9
