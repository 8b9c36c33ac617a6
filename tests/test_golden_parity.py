"""Parity with the official implementation on every golden case under every config.

Likelihoods, rates and the meta-metric must match within 1e-5; every per-step
feature must be bit-identical (float32); ADE differs only by float32
summation order.
"""
from __future__ import annotations

import json
from functools import lru_cache

import numpy as np
import pytest

from conftest import SHARED, require_shared
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.config import load_config
from wosac_eval.metrics.scenario_metrics import bucket_metrics, scenario_metrics
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import sim_agents_submission_pb2

CASES = sorted(p.name[: -len(".json")] for p in (SHARED / "golden").glob("*.json")) if (
    SHARED / "golden").is_dir() else ["(no ../shared)"]
CONFIGS = {
    "2025": "2025", "2024": "2024", "2023": "2023",
    "test": "official-configs/test_config.textproto",
    "test_dependent": "official-configs/test_config_dependent_timesteps.textproto",
}
EXACT_FEATURES = (
    "object_id", "object_type", "valid", "linear_speed", "linear_acceleration", "angular_speed",
    "angular_acceleration", "distance_to_nearest_object", "collision_per_step", "time_to_collision",
    "distance_to_road_edge", "offroad_per_step", "traffic_light_violation_per_step",
)


@lru_cache(maxsize=None)
def _scenarios() -> dict:
    return {s.scenario_id: s for s, _ in iter_scenarios(SHARED / "womd")}


@lru_cache(maxsize=None)
def _features(case: str):
    raw = (SHARED / "golden" / f"{case}.binproto").read_bytes()
    rollouts = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw).scenario_rollouts[0]
    return scenario_features(scenario_arrays(_scenarios()[rollouts.scenario_id]), rollout_arrays(rollouts))


def _config(name: str):
    value = CONFIGS[name]
    return load_config(value if value in ("2025", "2024", "2023") else SHARED / value)


@pytest.mark.parametrize("case", CASES)
def test_features_bit_identical(case):
    require_shared()
    log, sim = _features(case)
    golden = np.load(SHARED / "golden" / f"{case}.features.npz")
    for prefix, ours in (("log_", log), ("sim_", sim)):
        for name in EXACT_FEATURES:
            expected = golden[prefix + name]
            actual = np.asarray(getattr(ours, name))
            assert actual.shape == expected.shape, (prefix + name, actual.shape, expected.shape)
            # NaN where the official value is NaN (padded central differences), equal elsewhere.
            np.testing.assert_array_equal(actual, expected, err_msg=f"{case}: {prefix}{name}")
        np.testing.assert_allclose(ours.average_displacement_error,
                                   golden[prefix + "average_displacement_error"], rtol=1e-6, atol=1e-6,
                                   err_msg=f"{case}: {prefix}average_displacement_error")


@pytest.mark.parametrize("config_name", list(CONFIGS))
@pytest.mark.parametrize("case", CASES)
def test_metrics_match_official(case, config_name):
    require_shared()
    golden = json.loads((SHARED / "golden" / f"{case}.json").read_text())["metrics"][config_name]
    config = _config(config_name)
    log, sim = _features(case)
    ours = scenario_metrics(config, log, sim)
    expected_fields = {k: v for k, v in golden.items() if k != "buckets"}
    assert set(expected_fields) <= set(ours)
    for field, expected in expected_fields.items():
        assert ours[field] == pytest.approx(expected, abs=1e-5), field
    buckets = bucket_metrics(config, ours)
    for field, expected in golden["buckets"].items():
        assert buckets[field] == pytest.approx(expected, abs=1e-5), f"buckets.{field}"
