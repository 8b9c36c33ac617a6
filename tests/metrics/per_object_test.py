"""Per-object values (`metrics.per_object`): each scene field is the count-weighted geometric mean of its
objects' likelihoods, and the per-rollout event flags count what the scene's rates count.

On every golden case of both challenges under every config of its set: the synthetic oracle cases of
`tests/data` always, the real WOMD scenes and the Scenario Generation cases of ../shared when present
(skipped, saying why, when absent).

The identity is exact in real arithmetic (the official code averages the log-likelihoods over the
counted samples of all objects together, or over the objects for an indicator). Measured: against the
scene field recomputed in float64 from the same log-likelihoods, 4.4e-8 relative at worst (the objects'
float32 likelihoods). The reported field is the official float32 one: its mean log-likelihood is a
float32 sum in TensorFlow's order, so it lies within that sum's rounding bound of the identity
(`_float32_field_bound`, derived from the order, not measured).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from support import golden
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.per_object import EVENTS, PerObjectMetrics, per_object_metrics
from wosac_eval.metrics.registry import LIKELIHOOD_FIELDS, METRICS
from wosac_eval.metrics.scenario_metrics import metric_log_likelihoods, scenario_metrics, validity_masks
from wosac_eval.scoring.scenario import score_scenario, score_scenario_per_object

CASES = golden.all_cases()
RELATIVE_EXACT = 1e-7  # against the scene field in float64 from the same log-likelihoods
UNIT = 2.0**-24  # float32's unit roundoff


@lru_cache(maxsize=4)
def _features(case_set, case):
    return scenario_features(*golden.inputs(case_set, case), challenge=case_set.challenge)


def _relative(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


def _float32_field_bound(values: np.ndarray) -> float:
    """How far, relatively, the official float32 field can lie from exp(the exact mean of `values`).

    The official float32 sum of n values passes each through at most d additions (Eigen's order: a
    chain of n // 32 blocks in a leaf of up to 8,192 values, then at most 10 more additions, one more
    per level of the tree above the leaves), so it is off by at most d u sum|x| (u = 2**-24); the
    division adds u |mean|, and `exp` and the objects' float32 likelihoods u each (relative).
    """
    n = values.size
    depth = min(n, 8192) // 32 + 10 + int(np.ceil(np.log2(max(1.0, n / 8192))))
    mean = abs(values.mean())
    return depth * UNIT * np.abs(values).sum() / n + UNIT * mean + 3 * UNIT


@pytest.mark.parametrize("case_set, case", CASES)
def test_scene_fields_are_count_weighted_geometric_means(case_set, case):
    golden.skip_if_absent(case_set, case)
    log, sim = _features(case_set, case)
    for config_name in case_set.configs:
        config = golden.config(case_set, config_name)
        lls = metric_log_likelihoods(config, log, sim)
        fields = scenario_metrics(config, log, sim, lls)
        per_object = per_object_metrics(config, log, sim, lls)
        masks = validity_masks(log)
        for metric in METRICS:
            field = metric.output
            where = f"{config_name}: {field}"
            values, counts = per_object.likelihood[field], per_object.count[field]
            assert values.dtype == np.float32 and counts.dtype == np.int32, where
            assert values.shape == counts.shape == (per_object.num_objects,), where
            # The weights: an object's counted samples (its steps under the metric's mask), 1 for an indicator.
            want_counts = (
                np.ones(per_object.num_objects, np.int32) if metric.per_object else masks[metric.mask].sum(axis=-1)
            )
            np.testing.assert_array_equal(counts, want_counts, err_msg=where)
            np.testing.assert_array_equal(np.isnan(values), counts == 0, err_msg=where)
            # The identity, by hand: prod_i L_i ** (n_i / sum n), and as the method computes it.
            counted = counts > 0
            weights = counts[counted] / counts.sum()
            by_hand = float(np.exp((weights * np.log(values[counted].astype(np.float64))).sum()))
            assert by_hand == pytest.approx(per_object.scene_likelihood(field), rel=1e-12), where
            ll, mask = lls[metric.name]
            ll = np.asarray(ll, np.float64)
            bound = _float32_field_bound(ll if mask is None else ll[mask])
            assert _relative(by_hand, fields[field]) <= bound, (where, by_hand, fields[field], bound)
            exact = np.exp(ll.mean() if mask is None else ll[mask].sum() / mask.sum())
            assert _relative(by_hand, exact) <= RELATIVE_EXACT, (where, by_hand, exact)
            # Each object's value is its own mean log-likelihood's exp.
            for k in np.flatnonzero(counted):
                own = ll[k] if mask is None else ll[k][mask[k]].mean()
                assert _relative(float(values[k]), float(np.exp(own))) <= 1e-6, (where, k)


@pytest.mark.parametrize("case_set, case", CASES)
def test_event_flags_count_what_the_scene_rates_count(case_set, case):
    golden.skip_if_absent(case_set, case)
    log, sim = _features(case_set, case)
    config = golden.config(case_set, case_set.configs[0])
    fields = scenario_metrics(config, log, sim)
    per_object = per_object_metrics(config, log, sim)
    np.testing.assert_array_equal(per_object.object_id, log.object_id)
    np.testing.assert_array_equal(per_object.object_type, log.object_type[0])
    valid = log.valid[0]
    num_rollouts = sim.linear_speed.shape[0]
    for event, rate in EVENTS.items():
        flags, first = per_object.flags[event], per_object.first_step[event]
        assert flags.shape == first.shape == (num_rollouts, per_object.num_objects), event
        assert flags.dtype == bool and first.dtype == np.int32, event
        # The scene's rate is the share of flagged (rollout, object) pairs (float32 as stored).
        assert float(np.float32(per_object.rate(event))) == fields[rate], event
        per_step = getattr(sim, f"{event}_per_step") & valid
        np.testing.assert_array_equal(flags, per_step.any(axis=-1), err_msg=event)
        np.testing.assert_array_equal(first == -1, ~flags, err_msg=event)
        for r, k in zip(*np.nonzero(flags)):
            step = first[r, k]
            assert per_step[r, k, step] and not per_step[r, k, :step].any(), (event, r, k)


def test_indicator_likelihoods_score_the_flags_of_the_rollouts():
    """The per-object indicator likelihood is the Bernoulli estimate of the object's logged flag under
    its 32 rollouts' flags (the 2025 config's pseudocount): checked by hand on one oracle case."""
    case_set = golden.SETS[2]
    case = next(c for c in case_set.cases if "red-light" in c)
    log, sim = _features(case_set, case)
    config = golden.config(case_set, "2025")
    per_object = per_object_metrics(config, log, sim)
    log_flags = (log.collision_per_step & log.valid)[0].any(axis=-1)
    sim_flags = per_object.flags["collision"]
    pseudo = np.float32(config.collision_indication.bernoulli.additive_smoothing_pseudocount)
    for k in range(per_object.num_objects):
        hits = int(sim_flags[:, k].sum()) if log_flags[k] else int((~sim_flags[:, k]).sum())
        probability = (np.float32(hits) + pseudo) / np.float64(np.float32(sim_flags.shape[0]) + 2 * pseudo)
        assert per_object.likelihood["collision_indication_likelihood"][k] == pytest.approx(probability, rel=1e-6)


def test_the_scoring_entry_point_gives_the_same_values_beside_an_unchanged_row():
    case_set = golden.SETS[2]
    case = case_set.cases[0]
    scenario, rollouts = golden.inputs(case_set, case)
    log, sim = _features(case_set, case)
    config = golden.config(case_set, "2025")
    got = score_scenario_per_object(scenario, rollouts, "2025")
    want = per_object_metrics(config, log, sim)
    assert isinstance(got, PerObjectMetrics)
    for name in ("likelihood", "count", "flags", "first_step"):
        for key, value in getattr(want, name).items():
            np.testing.assert_array_equal(getattr(got, name)[key], value, err_msg=f"{name}[{key}]")
    row = score_scenario(scenario, rollouts, "2025")
    assert "per_object" not in row and set(LIKELIHOOD_FIELDS) <= set(row)
    lls = metric_log_likelihoods(config, log, sim)
    for metric in METRICS:
        ll, mask = lls[metric.name]
        ll = np.asarray(ll, np.float64)
        bound = _float32_field_bound(ll if mask is None else ll[mask])
        assert _relative(got.scene_likelihood(metric.output), row[metric.output]) <= bound, metric.output
