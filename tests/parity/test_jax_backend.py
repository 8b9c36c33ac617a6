"""The jax backend: features bit-identical to numpy (and to the official outputs) on CPU.

Covers the golden cases (real scenarios, ../shared) and the synthetic oracle
cases (in the repository), batched calls against per-scenario calls, and
padding to larger buckets. Compiled functions are shared across the module:
each bucket compiles once.
"""
from __future__ import annotations

import json
from functools import lru_cache

import numpy as np
import pytest

# Imported first: it restricts XLA's CPU code generation (no fused multiply-add)
# before JAX starts its CPU backend.
from wosac_eval.backends import jax_backend

from support import golden as cases
from support.paths import SHARED, require_shared
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.config import load_config
from wosac_eval.metrics.scenario_metrics import bucket_metrics, scenario_metrics

ORACLE = cases.ORACLE


def _assert_features_equal(ours, expected: dict, names, where: str) -> None:
    for prefix, features in (("log_", ours[0]), ("sim_", ours[1])):
        for name in names:
            actual = np.asarray(getattr(features, name))
            wanted = expected[prefix + name]
            assert actual.shape == wanted.shape, (where, prefix + name, actual.shape, wanted.shape)
            np.testing.assert_array_equal(actual, wanted, err_msg=f"{where}: {prefix}{name}")


def _as_dict(pair) -> dict:
    return {f"{prefix}{name}": getattr(features, name)
            for prefix, features in (("log_", pair[0]), ("sim_", pair[1]))
            for name in ("object_id", "object_type", "valid", "average_displacement_error",
                         *cases.EXACT_FEATURES)}


def _golden_inputs() -> dict:
    return {case: cases.golden_inputs(case) for case in cases.GOLDEN_CASES}


@lru_cache(maxsize=None)
def _golden_jax() -> dict:
    """All golden cases in one batched call."""
    inputs = _golden_inputs()
    return dict(zip(inputs, jax_backend.scenarios_features(list(inputs.values()))))


def _oracle_inputs() -> dict:
    return {case: cases.oracle_inputs(case) for case in cases.ORACLE_CASES}


@lru_cache(maxsize=None)
def _oracle_jax() -> dict:
    inputs = _oracle_inputs()
    return dict(zip(inputs, jax_backend.scenarios_features(list(inputs.values()))))


def test_no_fused_multiply_add_on_cpu():
    # Without this, float32 features differ from numpy in the last bit.
    assert not jax_backend.fma_contraction()


@pytest.mark.parametrize("n, minimum, expected", [(0, 8, 8), (1, 8, 8), (8, 8, 8), (9, 8, 16),
                                                  (5251, 64, 8192), (3, 1, 4), (0, 1, 1)])
def test_buckets_are_powers_of_two(n, minimum, expected):
    assert jax_backend.bucket(n, minimum) == expected


@pytest.mark.parametrize("n, expected", [(0, 64), (64, 64), (65, 128), (300, 384), (5251, 6144),
                                         (8192, 8192), (8193, 12288)])
def test_fine_buckets_pad_at_most_a_third(n, expected):
    assert jax_backend.fine_bucket(n) == expected


@pytest.mark.parametrize("case", cases.GOLDEN_CASES)
def test_golden_features_bit_identical_to_official_and_numpy(case):
    require_shared()
    ours = _golden_jax()[case]
    expected = np.load(SHARED / "golden" / f"{case}.features.npz")
    _assert_features_equal(ours, expected, cases.EXACT_FEATURES, case)
    _assert_features_equal(ours, _as_dict(scenario_features(*cases.golden_inputs(case))),
                           list(cases.EXACT_FEATURES) + ["average_displacement_error"], f"{case} vs numpy")
    for prefix, features in (("log_", ours[0]), ("sim_", ours[1])):
        np.testing.assert_allclose(features.average_displacement_error,
                                   expected[prefix + "average_displacement_error"], rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("config_name", list(cases.GOLDEN_CONFIGS))
@pytest.mark.parametrize("case", cases.GOLDEN_CASES)
def test_golden_metrics_match_official(case, config_name):
    require_shared()
    golden = json.loads((SHARED / "golden" / f"{case}.json").read_text())["metrics"][config_name]
    config = cases.golden_config(config_name)
    ours = scenario_metrics(config, *_golden_jax()[case])
    for field, expected in golden.items():
        if field != "buckets":
            assert ours[field] == pytest.approx(expected, abs=1e-5), field
    for field, expected in golden["buckets"].items():
        assert bucket_metrics(config, ours)[field] == pytest.approx(expected, abs=1e-5), f"buckets.{field}"


@pytest.mark.parametrize("case", cases.ORACLE_CASES)
def test_oracle_features_bit_identical_to_official_and_numpy(case):
    ours = _oracle_jax()[case]
    _assert_features_equal(ours, np.load(ORACLE / f"{case}.features.npz"), tuple(f for f in cases.EXACT_FEATURES if f != "object_type"), case)
    numpy_features = _as_dict(scenario_features(*_oracle_inputs()[case]))
    _assert_features_equal(ours, numpy_features, list(cases.EXACT_FEATURES)
                           + ["average_displacement_error"], f"{case} vs numpy")


@pytest.mark.parametrize("config_name", cases.ORACLE_CONFIGS)
@pytest.mark.parametrize("case", cases.ORACLE_CASES)
def test_oracle_metrics_match_official(case, config_name):
    golden = json.loads((ORACLE / f"{case}.json").read_text())["metrics"][config_name]
    config = load_config(config_name)
    ours = scenario_metrics(config, *_oracle_jax()[case])
    for field, expected in golden.items():
        if field != "buckets":
            assert ours[field] == pytest.approx(expected, abs=1e-5), field


def test_batched_call_equals_per_scenario_calls():
    inputs = _oracle_inputs()
    batched = _oracle_jax()
    # Two scenes that share a bucket with others in the batched call, scored alone.
    for case in list(inputs)[:2]:
        alone = jax_backend.scenario_features(*inputs[case])
        _assert_features_equal(alone, _as_dict(batched[case]),
                               list(cases.EXACT_FEATURES) + ["average_displacement_error"],
                               f"{case} alone vs batched")


def test_padding_to_larger_buckets_changes_nothing():
    inputs = _oracle_inputs()
    case = next(c for c in inputs if "red-light" in c)
    key = jax_backend.prepare(*inputs[case]).bucket_key
    larger = tuple(2 * k for k in key[3:])  # objects, evaluated, road-edge segments, signals, lane segments
    padded = jax_backend.scenarios_features([inputs[case]], min_bucket=larger)[0]
    _assert_features_equal(padded, _as_dict(_oracle_jax()[case]),
                           list(cases.EXACT_FEATURES) + ["average_displacement_error"],
                           f"{case} padded to {larger}")


TIMESERIES = ("linear_speed", "linear_acceleration", "angular_speed", "angular_acceleration",
              "distance_to_nearest_object", "time_to_collision", "distance_to_road_edge")
INDICATORS = {"collision_indication": "collision_per_step", "offroad_indication": "offroad_per_step",
              "traffic_light_violation": "traffic_light_violation_per_step"}


@pytest.mark.parametrize("config_name", ["2025", "2023"])
def test_estimators_under_jit_equal_numpy(config_name):
    import jax

    from wosac_eval.estimators import likelihoods
    config = load_config(config_name)
    case = next(c for c in cases.ORACLE_CASES if "collision" in c)
    log, sim = _oracle_jax()[case]
    for metric in TIMESERIES:
        feature_config = getattr(config, metric)
        expected = likelihoods.timeseries_log_likelihood(feature_config, getattr(log, metric)[0],
                                                         getattr(sim, metric))
        fn = jax.jit(lambda lv, sv: likelihoods.timeseries_log_likelihood(feature_config, lv, sv))
        with jax.enable_x64(True):
            actual = np.asarray(fn(getattr(log, metric)[0], getattr(sim, metric)))
        assert actual.dtype == expected.dtype
        np.testing.assert_array_equal(actual, expected, err_msg=f"{config_name}: {metric}")
    for metric, feature in INDICATORS.items():
        feature_config = getattr(config, metric)
        log_flags, sim_flags = getattr(log, feature)[0].any(axis=-1), getattr(sim, feature).any(axis=-1)
        expected = likelihoods.scenario_level_log_likelihood(feature_config, log_flags, sim_flags)
        fn = jax.jit(lambda lv, sv: likelihoods.scenario_level_log_likelihood(feature_config, lv, sv))
        with jax.enable_x64(True):
            actual = np.asarray(fn(log_flags, sim_flags))
        np.testing.assert_array_equal(actual, expected, err_msg=f"{config_name}: {metric}")


def test_kernel_density_under_jit_matches_numpy():
    import jax

    from wosac_eval.estimators import likelihoods
    rng = np.random.default_rng(3)
    log, sim = rng.normal(size=(4, 6)).astype(np.float32), rng.normal(size=(4, 32)).astype(np.float32)
    expected = likelihoods.kernel_density_log_likelihood(0.5, log, sim)
    with jax.enable_x64(True):
        actual = np.asarray(jax.jit(lambda a, b: likelihoods.kernel_density_log_likelihood(0.5, a, b))(log, sim))
    # Equal here too, but not guaranteed: XLA's float64 exp/log and the order of the float64 mean
    # differ from numpy's, which can move a float32 rounding by one unit.
    np.testing.assert_allclose(actual, expected, rtol=1e-6)


def test_scenario_without_signals_or_lanes_matches_numpy():
    import dataclasses
    inputs = _oracle_inputs()
    case = next(c for c in inputs if "red-light" in c)
    scenario, rollouts = inputs[case]
    for variant in (dataclasses.replace(scenario, signals=None),
                    dataclasses.replace(scenario, lanes=(), lane_ids=scenario.lane_ids[:0])):
        expected = _as_dict(scenario_features(variant, rollouts))
        assert not expected["sim_traffic_light_violation_per_step"].any()
        _assert_features_equal(jax_backend.scenario_features(variant, rollouts), expected,
                               list(cases.EXACT_FEATURES), f"{case} without signals or lanes")
