import dataclasses
import json

import numpy as np
import pytest

from wosac_eval.results.compare import (
    BETTER,
    METRICS,
    NO_DIFFERENCE,
    NOT_TESTED,
    WORSE,
    CompareError,
    Gate,
    canonical_metric,
    compare_results,
)
from wosac_eval.results.compare_text import format_table
from wosac_eval.results.stats import PairedSettings
from wosac_eval.scoring.result_reader import load_result
from wosac_eval.results.synthetic_results import LIKELIHOODS, WEIGHTS_2025, result_json, synthetic_scenarios

FAST = PairedSettings(n_boot=400, n_perm=400)


def _load(tmp_path, data, name, weights=None):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return load_result(path, weights_for=lambda config: weights)


def _pair(
    tmp_path,
    n=300,
    base_kwargs=None,
    new_kwargs=None,
    weights=None,
    base_slice=slice(None),
    new_slice=slice(None),
    base_config="2025",
    new_config="2025",
):
    base = result_json(synthetic_scenarios(n, seed=0, **(base_kwargs or {}))[base_slice], config=base_config)
    new = result_json(synthetic_scenarios(n, seed=0, **(new_kwargs or {}))[new_slice], config=new_config)
    return _load(tmp_path, base, "base.json", weights), _load(tmp_path, new, "new.json", weights)


def test_identical_results_show_no_difference(tmp_path):
    base, new = _pair(tmp_path)
    c = compare_results(base, new, gates=[Gate.parse("metametric:0")], settings=FAST)
    assert c.num_shared == 300
    assert all("no per-scenario values" in w for w in c.warnings)  # only the aggregate-only bucket note
    for m in c.metrics:
        if m.paired:
            assert (m.difference, m.ci_low, m.ci_high, m.p_value) == (0.0, 0.0, 0.0, 1.0), m.metric
            assert m.verdict == NO_DIFFERENCE
        else:  # aggregate-only buckets: the files' own aggregates, identical
            assert m.difference == 0.0 and m.verdict == NOT_TESTED
    assert c.passed


def test_constant_improvement_is_detected_on_every_shifted_metric(tmp_path):
    shift = {f: 0.01 for f in LIKELIHOODS}
    base, new = _pair(tmp_path, new_kwargs={"shift": shift})
    c = compare_results(base, new, settings=FAST)
    mm = c.metric("metametric")
    assert mm.difference == pytest.approx(0.01, abs=1e-12)  # the 2025 weights sum to 1
    assert mm.ci_low == pytest.approx(0.01) and mm.ci_high == pytest.approx(0.01)
    assert mm.p_value == pytest.approx(1 / 401) and mm.verdict == BETTER
    for f in LIKELIHOODS:
        assert c.metric(f).verdict == BETTER
    for f in ("simulated_collision_rate", "min_ade"):
        assert c.metric(f).verdict == NO_DIFFERENCE and c.metric(f).difference == 0.0


def test_lower_is_better_metrics_are_judged_the_right_way(tmp_path):
    base, new = _pair(
        tmp_path, new_kwargs={"shift": {"simulated_collision_rate": 0.01, "min_average_displacement_error": -0.2}}
    )
    c = compare_results(
        base, new, gates=[Gate.parse("simulated_collision_rate:0.005"), Gate.parse("min_ade:0")], settings=FAST
    )
    rate = c.metric("simulated_collision_rate")
    assert rate.verdict == WORSE and rate.regression == pytest.approx(0.01)
    assert c.metric("min_ade").verdict == BETTER
    assert [g.passed for g in c.gates] == [False, True]
    assert not c.passed


def test_noisy_regression_fails_a_tight_gate_and_passes_a_loose_one(tmp_path):
    shift = {"collision_indication_likelihood": -0.04}  # weight 0.25: metametric -0.01
    base, new = _pair(tmp_path, new_kwargs={"shift": shift, "jitter": 0.02})
    c = compare_results(
        base, new, gates=[Gate.parse("metametric:0.005"), Gate.parse("realism_meta_metric:0.02")], settings=FAST
    )
    mm = c.metric("metametric")
    assert mm.verdict == WORSE and mm.ci_low < -0.01 < mm.ci_high
    assert [g.passed for g in c.gates] == [False, True]


def test_only_significant_gate_ignores_a_noise_level_regression(tmp_path):
    # Pure noise (no shift) in 30 scenarios: pick a seed whose estimate is slightly worse but not significant.
    for jitter_seed in range(50):
        base, new = _pair(tmp_path, n=30, new_kwargs={"jitter": 0.05, "jitter_seed": jitter_seed})
        c = compare_results(base, new, metrics=["metametric"], gates=[Gate.parse("metametric:0")], settings=FAST)
        mm = c.metric("metametric")
        if mm.regression > 0 and mm.verdict == NO_DIFFERENCE:
            break
    else:
        pytest.fail("no seed gave a non-significant regression")
    assert not c.passed
    lenient = compare_results(
        base, new, metrics=["metametric"], gates=[Gate.parse("metametric:0")], only_significant=True, settings=FAST
    )
    assert lenient.passed and "not significant" in lenient.gates[0].reason


def test_per_scenario_buckets_are_tested_when_weights_are_known(tmp_path):
    shift = {"collision_indication_likelihood": 0.045}  # interactive weights 0.1, 0.25, 0.1 -> +0.025
    base, new = _pair(tmp_path, new_kwargs={"shift": shift}, weights=WEIGHTS_2025)
    c = compare_results(base, new, settings=FAST)
    inter = c.metric("interactive_metrics")
    assert inter.paired and inter.difference == pytest.approx(0.045 * 0.25 / 0.45)
    assert inter.verdict == BETTER
    assert c.metric("kinematic_metrics").verdict == NO_DIFFERENCE
    assert not any("no per-scenario values" in w for w in c.warnings)


def test_aggregate_only_buckets_are_compared_without_statistics(tmp_path):
    base, new = _pair(tmp_path, new_kwargs={"shift": {"offroad_indication_likelihood": -0.02}})
    c = compare_results(base, new, gates=[Gate.parse("map_based_metrics:0.001")], settings=FAST)
    mb = c.metric("map_based_metrics")
    assert not mb.paired and mb.ci_low is None and mb.verdict == NOT_TESTED
    # Map-based weights 0.05, 0.25, 0.05: -0.02 on offroad moves the bucket by -0.02 * 0.25 / 0.35.
    assert mb.difference == pytest.approx(-0.02 * 0.25 / 0.35, abs=1e-9)
    assert not c.gates[0].passed
    assert any("no per-scenario values" in w for w in c.warnings)


def test_different_scenario_sets_compare_the_shared_ones_and_warn(tmp_path):
    base, new = _pair(
        tmp_path, base_slice=slice(0, 200), new_slice=slice(50, 300), new_kwargs={"shift": {"metametric": 0.003}}
    )
    c = compare_results(base, new, settings=FAST)
    assert (c.num_shared, c.num_base_only, c.num_new_only) == (150, 50, 100)
    assert c.metric("metametric").difference == pytest.approx(0.003)
    assert any("scenario sets differ" in w and "50 only in base" in w and "100 only in new" in w for w in c.warnings)


def test_no_shared_scenario_is_an_error(tmp_path):
    base, new = _pair(tmp_path, base_slice=slice(0, 10), new_slice=slice(10, 20))
    with pytest.raises(CompareError, match="share no scenario"):
        compare_results(base, new, settings=FAST)
    base, new = _pair(tmp_path, base_slice=slice(0, 10), new_slice=slice(5, 20))
    with pytest.raises(CompareError, match="share only 5 scenarios"):
        compare_results(base, new, min_shared=6, settings=FAST)
    c = compare_results(base, new, settings=FAST)
    assert any("only 5 shared scenarios" in w for w in c.warnings) and c.exact_permutation


def test_different_configs_warn(tmp_path):
    base, new = _pair(tmp_path, new_config="2024")
    c = compare_results(base, new, settings=FAST)
    assert any("different configs" in w and "'2025'" in w and "'2024'" in w for w in c.warnings)


def test_metric_selection_aliases_and_unknown_names(tmp_path):
    base, new = _pair(tmp_path, n=50)
    c = compare_results(
        base,
        new,
        metrics=["realism_meta_metric", "min_ade"],
        gates=[Gate.parse("simulated_offroad_rate:0.01")],
        settings=FAST,
    )
    assert [m.metric for m in c.metrics] == ["metametric", "min_average_displacement_error", "simulated_offroad_rate"]
    assert canonical_metric(" MetaMetric ") == "metametric"
    with pytest.raises(CompareError, match="unknown metric 'speed'.*linear_speed_likelihood"):
        canonical_metric("speed")
    for bad, message in [
        ("metametric", "expected METRIC:DELTA"),
        ("metametric:x", "not a number"),
        ("metametric:-1", ">= 0"),
        ("nope:0.1", "unknown metric"),
    ]:
        with pytest.raises(CompareError, match=message):
            Gate.parse(bad)


def test_holm_adjustment_changes_only_the_verdicts_basis(tmp_path):
    base, new = _pair(tmp_path, n=100, new_kwargs={"jitter": 0.03, "jitter_seed": 3})
    raw = compare_results(base, new, settings=FAST)
    holm = compare_results(base, new, settings=dataclasses.replace(FAST, adjust="holm"))
    for a, b in zip(raw.metrics, holm.metrics):
        assert a.p_value == b.p_value and a.p_holm == b.p_holm
        if a.paired:
            assert b.p_holm >= b.p_value
            assert (b.verdict != NO_DIFFERENCE) == (b.p_holm < 0.05 and b.difference != 0)


def test_json_and_table_outputs(tmp_path):
    base, new = _pair(tmp_path, n=60, new_kwargs={"shift": {"metametric": -0.01}})
    c = compare_results(base, new, gates=[Gate.parse("metametric:0.005")], settings=FAST)
    out = json.loads(json.dumps(c.to_json()))
    assert out["passed"] is False and out["scenarios"]["shared"] == 60
    assert [m["metric"] for m in out["metrics"]] == list(METRICS)
    assert out["gates"][0] == {
        "gate": "metametric:0.005",
        "metric": "metametric",
        "max_regression": 0.005,
        "regression": pytest.approx(0.01),
        "passed": False,
        "reason": out["gates"][0]["reason"],
    }
    table = format_table(c)
    header = next(line for line in table.splitlines() if line.startswith("metric"))
    assert header.split() == ["metric", "best", "base", "new", "diff", "95%", "CI", "p", "verdict"]
    row = next(line for line in table.splitlines() if line.startswith("metametric "))
    assert "-0.0100" in row and row.rstrip().endswith("WORSE")
    assert "gate metametric:0.005  FAIL" in table and "GATE FAILED" in table
    assert "metrics tested at alpha=0.05" in table


def test_paired_base_and_new_are_means_over_shared_scenarios(tmp_path):
    base, new = _pair(tmp_path, base_slice=slice(0, 80), new_slice=slice(20, 100))
    c = compare_results(base, new, metrics=["metametric"], settings=FAST)
    shared = base.values["metametric"][20:80]
    assert c.metric("metametric").base == pytest.approx(float(np.mean(shared)))


def test_gate_on_a_metric_neither_file_has_fails_with_a_reason(tmp_path):
    data = result_json(synthetic_scenarios(20, seed=0))
    data["buckets"] = {}  # no aggregate buckets, and no weights to compute them per scenario
    base, new = _load(tmp_path, data, "base.json"), _load(tmp_path, data, "new.json")
    c = compare_results(base, new, gates=[Gate.parse("kinematic_metrics:0.1")], settings=FAST)
    assert not c.passed and c.gates[0].regression is None
    assert "not in both results" in c.gates[0].reason
    assert any("kinematic_metrics: not in both results" in w for w in c.warnings)
    json.dumps(c.to_json(), allow_nan=False)  # strict JSON: no NaN anywhere


def test_relative_gates_scale_with_the_baseline(tmp_path):
    base, new = _pair(tmp_path, n=80, new_kwargs={"shift": {"metametric": -0.01}})
    base_mean = float(base.values["metametric"].mean())  # about 0.45: a 0.01 drop is about 2.2%
    c = compare_results(
        base, new, gates=[Gate.parse("metametric:2%"), Gate.parse("realism_meta_metric:3%")], settings=FAST
    )
    assert [g.passed for g in c.gates] == [False, True]
    assert c.gates[0].allowed == pytest.approx(0.02 * base_mean)
    assert c.gates[0].gate.spec == "metametric:2%" and c.gates[0].gate.relative
    assert "gate metametric:2%  FAIL" in format_table(c)
    with pytest.raises(CompareError, match="not a number"):
        Gate.parse("metametric:%")
