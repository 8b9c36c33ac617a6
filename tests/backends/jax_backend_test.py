"""The jax backend: features bit-identical to numpy (and to the official outputs) on CPU.

Covers every golden case of both challenges (`support.golden`), batched calls
against per-scenario calls, padding to larger buckets, and the estimators
under jit. Compiled functions are shared across the module: each bucket
compiles once.
"""

from __future__ import annotations

import dataclasses
import pickle
from functools import lru_cache, reduce

import numpy as np
import pytest

from wosac_eval.backends import jax_backend
from wosac_eval.backends.jax_driver import Sizes

from support import golden
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.config import load_config
from wosac_eval.metrics.scenario_metrics import bucket_metrics, scenario_metrics

CASES = golden.all_cases()


@lru_cache(maxsize=None)
def _set_prepared(case_set) -> dict:
    """Every case of a set prepared for the device: case -> `PreparedScenario`."""
    return {c: jax_backend.prepare(*golden.inputs(case_set, c), challenge=case_set.challenge) for c in case_set.cases}


@lru_cache(maxsize=None)
def _set_floor(case_set) -> Sizes:
    """The largest of each bucket size among a set's cases (`Sizes.at_least`): as `min_bucket`, every case
    falls in one bucket, so a set compiles one program per batch size instead of one per bucket its cases
    fall in (about 12 s each on 2 cores). Padding changes no bit, and a case in its own bucket is checked
    against the set's: test_padding_to_larger_buckets_changes_nothing."""
    return reduce(Sizes.at_least, (p.bucket_key.sizes for p in _set_prepared(case_set).values()))


@lru_cache(maxsize=None)
def _set_features(case_set) -> dict:
    """Every case of a set in one batched call, padded to the set's floor: case -> (log, sim)."""
    prepared = _set_prepared(case_set)
    return dict(zip(prepared, jax_backend.prepared_features(list(prepared.values()), min_bucket=_set_floor(case_set))))


def _numpy(case_set, case):
    return scenario_features(*golden.inputs(case_set, case), challenge=case_set.challenge)


def test_no_fused_multiply_add_on_cpu():
    # The test process opted in (tests/conftest.py); without it float32 features differ from numpy
    # in the last bit. exact_cpu() confirms it, as a program calls it.
    jax_backend.exact_cpu()
    assert not jax_backend.fma_contraction()


@pytest.mark.parametrize(
    "n, minimum, expected", [(0, 8, 8), (1, 8, 8), (8, 8, 8), (9, 8, 16), (5251, 64, 8192), (3, 1, 4), (0, 1, 1)]
)
def test_buckets_are_powers_of_two(n, minimum, expected):
    assert jax_backend.bucket(n, minimum) == expected


@pytest.mark.parametrize(
    "n, expected", [(0, 64), (64, 64), (65, 128), (300, 384), (5251, 6144), (8192, 8192), (8193, 12288)]
)
def test_fine_buckets_pad_at_most_a_third(n, expected):
    assert jax_backend.fine_bucket(n) == expected


# One test per case for the features and the metrics from them: the set's programs compile in one xdist
# worker, not in both (two tests of a case ran on either).
@pytest.mark.ci  # every golden case (a program or two per set, about 15 s each on 2 cores): the CI tier's
@pytest.mark.parametrize("case_set, case", CASES)
def test_features_and_metrics_bit_identical_to_official_and_numpy(case_set, case):
    golden.skip_if_absent(case_set, case)
    ours = _set_features(case_set)[case]
    golden.assert_features_equal(ours, golden.expected_features(case_set, case), case)
    golden.assert_features_equal(ours, golden.as_feature_dict(_numpy(case_set, case)), f"{case} vs numpy")
    log, sim = ours
    for config_name in case_set.configs:
        config = golden.config(case_set, config_name)
        expected = golden.expected_metrics(case_set, case, config_name)
        metrics = scenario_metrics(config, log, sim)
        # The official float32 values, bit for bit (the JAX features are; the metrics are numpy's).
        for field, value in expected.items():
            if field != "buckets":
                np.testing.assert_array_equal(np.float32(metrics[field]), np.float32(value), f"{config_name}: {field}")
        for field, value in expected["buckets"].items():
            got = np.float32(bucket_metrics(config, metrics)[field])
            np.testing.assert_array_equal(got, np.float32(value), f"buckets.{field}")


ORACLE = golden.SETS[2]


@pytest.mark.slow  # two programs of the set's bucket (batches of 8 and of 1): 25 s of compiling on 2 cores
def test_batched_call_equals_per_scenario_calls():
    batched = _set_features(ORACLE)
    # Two scenes of the batched call scored alone, in the same bucket: a batch of one.
    for case in ORACLE.cases[:2]:
        (alone,) = jax_backend.prepared_features([_set_prepared(ORACLE)[case]], min_bucket=_set_floor(ORACLE))
        golden.assert_features_equal(alone, golden.as_feature_dict(batched[case]), f"{case} alone vs batched")


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_padding_to_larger_buckets_changes_nothing():
    case = next(c for c in ORACLE.cases if "red-light" in c)
    key = _set_prepared(ORACLE)[case].bucket_key
    larger = key.sizes.with_counts(2 * k for k in key.sizes.as_tuple())  # objects, evaluated, every map size
    (padded,) = jax_backend.prepared_features([_set_prepared(ORACLE)[case]], min_bucket=larger)
    tight = jax_backend.scenario_features(*golden.inputs(ORACLE, case))  # its own bucket
    golden.assert_features_equal(padded, golden.as_feature_dict(tight), f"{case} padded to {larger}")
    golden.assert_features_equal(
        tight, golden.as_feature_dict(_set_features(ORACLE)[case]), f"{case} in the set's bucket"
    )


def test_a_scene_prepared_in_a_worker_process_has_the_same_bucket_key():
    """The pipelined file path prepares scenes in worker processes (pickled back) and finds the compiled
    program of each by its bucket key: a key that changed in the round trip traced the program again for
    every batch (20 s a batch on 2 cores)."""
    case = next(c for c in ORACLE.cases if "red-light" in c)
    prepared = jax_backend.prepare(*golden.inputs(ORACLE, case))
    back = pickle.loads(pickle.dumps(prepared))
    assert back.bucket_key == prepared.bucket_key and hash(back.bucket_key) == hash(prepared.bucket_key)
    assert back.layout == prepared.layout


TIMESERIES = (
    "linear_speed",
    "linear_acceleration",
    "angular_speed",
    "angular_acceleration",
    "distance_to_nearest_object",
    "time_to_collision",
    "distance_to_road_edge",
)
INDICATORS = {
    "collision_indication": "collision_per_step",
    "offroad_indication": "offroad_per_step",
    "traffic_light_violation": "traffic_light_violation_per_step",
}


@pytest.mark.slow  # the estimators of every field compiled per config: 100 s on 2 cores
@pytest.mark.parametrize("config_name", ["2025", "2023", "scenario_gen_2025"])
def test_estimators_under_jit_equal_numpy(config_name):
    import jax

    from wosac_eval.estimators import likelihoods

    config = load_config(config_name)
    case = next(c for c in ORACLE.cases if "collision" in c)
    log, sim = _set_features(ORACLE)[case]
    for metric in TIMESERIES:
        feature_config = getattr(config, metric)
        expected = likelihoods.timeseries_log_likelihood(feature_config, getattr(log, metric)[0], getattr(sim, metric))
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


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_scenario_without_signals_or_lanes_matches_numpy():
    case = next(c for c in ORACLE.cases if "red-light" in c)
    scenario, rollouts = golden.inputs(ORACLE, case)
    for variant in (
        dataclasses.replace(scenario, signals=None),
        dataclasses.replace(scenario, lanes=(), lane_ids=scenario.lane_ids[:0]),
    ):
        expected = golden.as_feature_dict(scenario_features(variant, rollouts))
        assert not expected["sim_traffic_light_violation_per_step"].any()
        golden.assert_features_equal(
            jax_backend.scenario_features(variant, rollouts), expected, f"{case} without signals or lanes"
        )
