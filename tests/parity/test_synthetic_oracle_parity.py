"""Parity with the official implementation on synthetic edge-case scenes.

The scenes come from `wosac_eval.sim` (red-light run, logged collision,
vehicles leaving the road, occlusions, dense following, large coordinates,
heading wrap-around); the expected outputs were produced by the official
implementation (`../shared/oracle/make_golden.py`, see tests/data/oracle/README.md).
These run everywhere: the data is in the repository.
"""
from __future__ import annotations

import json
from functools import lru_cache

import numpy as np
import pytest

from support.golden import EXACT_FEATURES, ORACLE, ORACLE_CASES, ORACLE_CONFIGS, oracle_inputs
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.config import load_config
from wosac_eval.metrics.scenario_metrics import bucket_metrics, scenario_metrics

DATA = ORACLE
CASES = ORACLE_CASES
# The per-step features compared bit for bit (the object types were not stored with these cases).
EXACT = tuple(f for f in EXACT_FEATURES if f != "object_type")
CONFIGS = ORACLE_CONFIGS


@lru_cache(maxsize=None)
def _features(case: str):
    return scenario_features(*oracle_inputs(case))


def test_cases_are_present():
    assert len(CASES) >= 5, "the synthetic oracle cases are missing from tests/data/oracle"


@pytest.mark.parametrize("case", CASES)
def test_features_bit_identical(case):
    log, sim = _features(case)
    golden = np.load(DATA / f"{case}.features.npz")
    for prefix, ours in (("log_", log), ("sim_", sim)):
        for name in EXACT:
            np.testing.assert_array_equal(np.asarray(getattr(ours, name)), golden[prefix + name],
                                          err_msg=f"{case}: {prefix}{name}")


@pytest.mark.parametrize("config_name", CONFIGS)
@pytest.mark.parametrize("case", CASES)
def test_metrics_match_official(case, config_name):
    golden = json.loads((DATA / f"{case}.json").read_text())["metrics"][config_name]
    config = load_config(config_name)
    log, sim = _features(case)
    ours = scenario_metrics(config, log, sim)
    for field, expected in golden.items():
        if field != "buckets":
            assert ours[field] == pytest.approx(expected, abs=1e-5), field
    buckets = bucket_metrics(config, ours)
    for field, expected in golden["buckets"].items():
        assert buckets[field] == pytest.approx(expected, abs=1e-5), f"buckets.{field}"
