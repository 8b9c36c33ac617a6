"""Parity with the official implementation on every golden case of both challenges, under every config.

Every per-step feature and the displacement error must be bit-identical
(float32, NaN where the official value is NaN); so must every likelihood, rate,
displacement error, meta-metric and bucket, compared as float32 (the official
values are float32 proto fields). The cases are whatever `support.golden.SETS`
holds: `../shared` (extended on every landing) and the synthetic oracle cases
in `tests/data`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from support import golden
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.scenario_metrics import bucket_metrics, scenario_metrics

CASES = golden.all_cases()


@lru_cache(maxsize=8)
def _features(case_set, case):
    return scenario_features(*golden.inputs(case_set, case), challenge=case_set.challenge)


def test_repository_cases_are_present():
    assert len(golden.SETS[2].cases) >= 5, "the sim agents oracle cases are missing from tests/data/oracle"
    assert len(golden.SETS[3].cases) >= 3, "the scenario gen oracle cases are missing from tests/data"


@pytest.mark.parametrize("case_set, case", CASES)
def test_features_bit_identical(case_set, case):
    golden.skip_if_absent(case_set, case)
    golden.assert_features_equal(_features(case_set, case), golden.expected_features(case_set, case), case)


@pytest.mark.parametrize("case_set, case", CASES)
def test_metrics_match_official(case_set, case):
    golden.skip_if_absent(case_set, case)
    log, sim = _features(case_set, case)
    for config_name in case_set.configs:
        expected = golden.expected_metrics(case_set, case, config_name)
        config = golden.config(case_set, config_name)
        ours = scenario_metrics(config, log, sim)
        fields = {k: v for k, v in expected.items() if k != "buckets"}
        assert set(fields) <= set(ours)
        for field, value in fields.items():
            _assert_official(ours[field], value, f"{case} {config_name}: {field}")
        buckets = bucket_metrics(config, ours)
        for field, value in expected["buckets"].items():
            _assert_official(buckets[field], value, f"{case} {config_name}: buckets.{field}")


def _assert_official(ours: float, official: float, where: str) -> None:
    """The official float32 value, bit for bit (NaN for NaN)."""
    if np.isnan(official):
        assert np.isnan(ours), where
    else:
        assert np.float32(ours).view(np.int32) == np.float32(official).view(np.int32), (where, ours, official)
