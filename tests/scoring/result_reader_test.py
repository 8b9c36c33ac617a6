import json
import re
from pathlib import Path

import numpy as np
import pytest

from wosac_eval.scoring.result_reader import (
    BUCKET_MEMBERS,
    SCENARIO_FIELDS,
    ResultError,
    load_result,
    parse_result,
    weighted_buckets,
)
from wosac_eval.results.synthetic_results import WEIGHTS_2025, result_json, synthetic_scenarios

from support.paths import SHARED


def _no_weights(config):
    return None


def _write(tmp_path, data, name="result.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def test_load_gives_one_array_per_field(tmp_path):
    data = result_json(synthetic_scenarios(25, seed=0))
    r = load_result(_write(tmp_path, data), weights_for=_no_weights)
    assert r.num_scenarios == 25 and r.config == "2025"
    assert set(SCENARIO_FIELDS) <= set(r.values)
    assert not any(b in r.values for b in BUCKET_MEMBERS)  # no weights, none in the file
    assert r.values["metametric"].shape == (25,)
    assert r.values["metametric"][3] == data["scenarios"][3]["metametric"]
    assert r.headline("realism_meta_metric") == data["buckets"]["realism_meta_metric"]
    assert r.per_scenario("min_ade") is r.values["min_average_displacement_error"]


def test_weighted_buckets_average_to_the_aggregate_buckets(tmp_path):
    data = result_json(synthetic_scenarios(40, seed=1))
    r = load_result(_write(tmp_path, data), weights_for=lambda config: WEIGHTS_2025)
    for bucket in BUCKET_MEMBERS:
        # A weighted mean is linear: the mean over scenarios of the per-scenario bucket is the bucket of the means.
        assert r.values[bucket].mean() == pytest.approx(data["buckets"][bucket], abs=1e-12)


def test_buckets_carried_per_scenario_are_used(tmp_path):
    scenarios = synthetic_scenarios(5, seed=2)
    for i, s in enumerate(scenarios):
        s.update(kinematic_metrics=0.1 * i, interactive_metrics=0.2, map_based_metrics=0.3)
    r = parse_result(result_json(scenarios), weights_for=_no_weights)
    np.testing.assert_allclose(r.values["kinematic_metrics"], [0.0, 0.1, 0.2, 0.3, 0.4])


def test_bucket_with_zero_weights_is_left_out():
    values = {f"{f}_likelihood": np.full(3, 0.5) for members in BUCKET_MEMBERS.values() for f in members}
    weights = dict(WEIGHTS_2025, distance_to_road_edge=0.0, offroad_indication=0.0, traffic_light_violation=0.0)
    out = weighted_buckets(values, weights)
    assert set(out) == {"kinematic_metrics", "interactive_metrics"}


def _official_weights(config_path: Path) -> dict[str, float]:
    text = config_path.read_text()
    return {
        m.group(1): float(m.group(2))
        for m in re.finditer(r"^(\w+): \{.*?metametric_weight: ([0-9.]+)", text, re.DOTALL | re.MULTILINE)
    }


def test_weighted_buckets_match_the_official_buckets_on_golden_outputs():
    golden = sorted((SHARED / "golden").glob("*.json")) if SHARED.is_dir() else []
    if not golden:
        pytest.skip(f"reference material not found at {SHARED} (golden/*.json)")
    weights = _official_weights(SHARED / "official-configs" / "challenge_2025_sim_agents_config.textproto")
    assert weights == WEIGHTS_2025
    for path in golden:
        metrics = json.loads(path.read_text())["metrics"]["2025"]
        values = {k: np.array([v]) for k, v in metrics.items() if k != "buckets"}
        buckets = weighted_buckets(values, weights)
        for name, value in buckets.items():
            assert value[0] == pytest.approx(metrics["buckets"][name], abs=1e-6), (path.name, name)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d.pop("scenarios"), "missing 'scenarios'"),
        (lambda d: d.pop("config"), "missing 'config'"),
        (
            lambda d: d["scenarios"][1].pop("offroad_indication_likelihood"),
            r"scenario 'scn000001' \(scenarios\[1\]\) has no field 'offroad_indication_likelihood'",
        ),
        (
            lambda d: d["scenarios"][2].update(metametric="high"),
            r"scenario 'scn000002' field 'metametric': expected a number, got 'high'",
        ),
        (
            lambda d: d["scenarios"][2].update(metametric=True),
            r"scenario 'scn000002' field 'metametric': expected a number, got True",
        ),
        (
            lambda d: d["scenarios"][1].update(min_average_displacement_error="0.5"),
            r"scenario 'scn000001' field 'min_average_displacement_error': expected a number, got '0.5'",
        ),
        (
            lambda d: d["scenarios"][1].update(linear_speed_likelihood=None),
            r"scenario 'scn000001' field 'linear_speed_likelihood': expected a number, got None",
        ),
        (lambda d: d["scenarios"].__setitem__(1, ["not", "an", "object"]), r"scenarios\[1\] is not an object"),
        (
            lambda d: d["scenarios"][2].update(simulated_offroad_rate=float("nan")),
            r"scenario 'scn000002' field 'simulated_offroad_rate': value is nan",
        ),
        (
            lambda d: d["scenarios"][2].update(scenario_id="scn000000"),
            r"scenario 'scn000000' appears twice \(scenarios\[0\] and scenarios\[2\]\)",
        ),
        (lambda d: d["scenarios"][0].pop("scenario_id"), r"scenarios\[0\] has no 'scenario_id'"),
        (lambda d: d["aggregate"].update(metametric=None), r"aggregate.metametric: expected a number"),
    ],
)
def test_bad_results_name_file_scenario_and_field(tmp_path, mutate, message):
    data = result_json(synthetic_scenarios(3, seed=0))
    mutate(data)
    path = _write(tmp_path, data, "bad.json")
    with pytest.raises(ResultError, match=message) as e:
        load_result(path, weights_for=_no_weights)
    assert str(path) in str(e.value)


def test_unreadable_files(tmp_path):
    with pytest.raises(ResultError, match="no such file"):
        load_result(tmp_path / "missing.json")
    bad = tmp_path / "truncated.json"
    bad.write_text('{"config": "2025", "scenarios": [')
    with pytest.raises(ResultError, match="not valid JSON"):
        load_result(bad)
    listing = tmp_path / "list.json"
    listing.write_text("[]")
    with pytest.raises(ResultError, match="expected a JSON object"):
        load_result(listing)
