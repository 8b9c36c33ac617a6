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

from support.golden import EXACT_FEATURES, GOLDEN_CASES, GOLDEN_CONFIGS as CONFIGS, golden_config as _config, golden_inputs
from support.paths import SHARED, require_shared
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.scenario_metrics import bucket_metrics, scenario_metrics

CASES = GOLDEN_CASES


@lru_cache(maxsize=None)
def _features(case: str):
    return scenario_features(*golden_inputs(case))


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
