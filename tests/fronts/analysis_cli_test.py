"""The analysis on the command line: `criticality`, `score --select`, `compare --stratify`, the report section."""

from __future__ import annotations

import csv
import json

import pytest

from support.runs import run_cli
from wosac_eval.analysis.scenario_set_criticality import parse_selection, scenario_set_criticality, select_scenarios
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import make_submission


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Eight demo-like scenes, two policies scored (full results, as `score -o` writes them)."""
    root = tmp_path_factory.mktemp("analysis")
    shards = scenes.write_scenario_shards(scenes.generate_scenes(8, seed=4), root / "scenarios")
    out = {"root": root, "scenarios": [str(p) for p in shards]}
    for policy in ("constant_velocity", "idm"):
        submission = make_submission(shards, policy, root / policy, num_shards=1)
        out[policy] = submission
        done = run_cli(
            "score",
            "--scenarios",
            *out["scenarios"],
            "--submission",
            str(submission),
            "-o",
            str(root / f"{policy}.json"),
        )
        assert done.returncode == 0, done.stderr
        out[f"{policy}.json"] = root / f"{policy}.json"
    return out


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_every_row_carries_the_analysis(runs):
    result = json.loads(runs["idm.json"].read_text())
    for row in result["scenarios"]:
        assert 0.0 <= row["criticality"]["score"] <= 1.0
        assert set(row["criticality"]["components"]) >= {"braking", "time_to_collision", "near_miss", "rarity"}
        assert 0.0 <= row["driving"]["score"] <= 1.0
        assert "vehicle" in row["by_object_type"]
    summary = result["analysis"]
    assert summary["driving"]["num_scenarios"] == 8
    assert summary["by_object_type"]["vehicle"]["num_scenarios"] == 8


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_criticality_table_ranks_the_set_like_the_result_rows(runs, tmp_path):
    done = run_cli("criticality", "--scenarios", *runs["scenarios"], "-o", str(tmp_path / "c.csv"), "--per-step")
    assert done.returncode == 0, done.stderr
    rows = list(csv.DictReader((tmp_path / "c.csv").open()))
    assert [int(r["rank"]) for r in rows] == list(range(1, 9))
    scores = [float(r["score"]) for r in rows]
    assert scores == sorted(scores, reverse=True)
    assert "step_90" in rows[0] and "raw_time_to_collision" in rows[0]
    # The same scores as the scored rows (rarity against the same set).
    scored = {
        r["scenario_id"]: r["criticality"]["score"] for r in json.loads(runs["idm.json"].read_text())["scenarios"]
    }
    for row in rows:
        assert float(row["score"]) == pytest.approx(scored[row["scenario_id"]], abs=1e-12)
    as_json = run_cli("criticality", "--scenarios", *runs["scenarios"], "-o", str(tmp_path / "c.json"))
    assert (
        as_json.returncode == 0
        and json.loads((tmp_path / "c.json").read_text())[0]["scenario_id"] == rows[0]["scenario_id"]
    )


@pytest.mark.slow  # its module's fixture scores the demo's policies first (10 s): out of the fast tier
def test_criticality_writes_parquet(runs, tmp_path):
    pq = pytest.importorskip("pyarrow.parquet", reason="pyarrow (the test extra) writes .parquet")
    done = run_cli("criticality", "--scenarios", *runs["scenarios"], "-o", str(tmp_path / "c.parquet"))
    assert done.returncode == 0, done.stderr
    table = pq.read_table(tmp_path / "c.parquet")
    assert table.num_rows == 8 and table.column("rank").to_pylist() == list(range(1, 9))


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_criticality_refuses_bad_outputs_at_once(runs, tmp_path):
    for output, message in (
        (tmp_path / "c.txt", "the suffix chooses the format"),
        (tmp_path / "nowhere" / "c.csv", "nowhere"),
    ):
        done = run_cli("criticality", "--scenarios", *runs["scenarios"], "-o", str(output))
        assert done.returncode == 2 and message in done.stderr and "Traceback" not in done.stderr


def test_selection_rules():
    assert parse_selection("top:0.1") == ("fraction", 0.1)
    assert parse_selection("top:1.0") == ("fraction", 1.0)
    assert parse_selection("top:25") == ("count", 25)
    for bad in ("top:0", "top:1.5", "bottom:3", "top:-1", "top:abc", "0.1"):
        with pytest.raises(ValueError, match="top:FRACTION"):
            parse_selection(bad)
    ranked = [{"scenario_id": f"s{i}"} for i in range(10)]
    assert select_scenarios(ranked, "top:0.25") == ["s0", "s1", "s2"]  # rounded up
    assert select_scenarios(ranked, "top:0.01") == ["s0"]  # at least one
    assert select_scenarios(ranked, "top:40") == [f"s{i}" for i in range(10)]


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_score_select_scores_the_long_tail_only(runs, tmp_path):
    ranked = scenario_set_criticality(runs["scenarios"])["scenarios"]
    done = run_cli(
        "score",
        "--scenarios",
        *runs["scenarios"],
        "--submission",
        str(runs["idm"]),
        "--select",
        "top:0.25",
        "-o",
        str(tmp_path / "tail.json"),
    )
    assert done.returncode == 0, done.stderr
    assert "selection top:0.25: the 2 most critical of 8" in done.stderr
    tail = json.loads((tmp_path / "tail.json").read_text())
    assert [r["scenario_id"] for r in tail["scenarios"]] == [
        r["scenario_id"]
        for r in json.loads(runs["idm.json"].read_text())["scenarios"]
        if r["scenario_id"] in {x["scenario_id"] for x in ranked[:2]}
    ]
    assert tail["selection"]["scenarios"] == 2 and tail["selection"]["of"] == 8
    assert tail["coverage"] == {"scored": 2, "expected": 2, "fraction": 1.0}
    full = {r["scenario_id"]: r for r in json.loads(runs["idm.json"].read_text())["scenarios"]}
    for row in tail["scenarios"]:  # rated against the whole set, scored as in the full run
        assert row["criticality"] == full[row["scenario_id"]]["criticality"]
        assert row["metametric"] == full[row["scenario_id"]]["metametric"]
    bad = run_cli("score", "--scenarios", *runs["scenarios"], "--submission", str(runs["idm"]), "--select", "top")
    assert bad.returncode == 2 and "--select 'top'" in bad.stderr


@pytest.mark.parametrize(
    "by, strata", [("criticality", {"low", "mid", "high", "long tail", "rest"}), ("object_type", {"vehicle"})]
)
@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_compare_stratified(runs, tmp_path, by, strata):
    done = run_cli(
        "compare",
        str(runs["constant_velocity.json"]),
        str(runs["idm.json"]),
        "--stratify",
        by,
        "--n-boot",
        "500",
        "--n-perm",
        "500",
        "--json",
    )
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)["stratified"]
    assert out["by"] == by and strata <= {r["stratum"] for r in out["strata"]}
    for row in out["strata"]:
        if row["num_scenarios"]:
            assert row["ci_low"] <= row["difference"] <= row["ci_high"]
            assert 0 < row["p_value"] <= row["p_holm"] <= 1
    assert "tests (strata x metrics)" in out["notes"][0]
    table = run_cli(
        "compare",
        str(runs["constant_velocity.json"]),
        str(runs["idm.json"]),
        "--stratify",
        by,
        "--n-boot",
        "200",
        "--n-perm",
        "200",
    )
    assert table.returncode == 0 and f"stratified by {by.replace('_', ' ')}" in table.stdout


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_compare_stratified_refuses_results_without_the_analysis(runs, tmp_path):
    old = json.loads(runs["idm.json"].read_text())
    for row in old["scenarios"]:
        row.pop("criticality"), row.pop("by_object_type"), row.pop("driving")
    (tmp_path / "old.json").write_text(json.dumps(old))
    for by in ("criticality", "object_type"):
        done = run_cli("compare", str(tmp_path / "old.json"), str(tmp_path / "old.json"), "--stratify", by)
        assert done.returncode == 2 and "score them again" in done.stderr, done.stderr


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_report_shows_realism_against_criticality(runs, tmp_path):
    done = run_cli("report", str(runs["idm.json"]), "--html", str(tmp_path / "r.html"))
    assert done.returncode == 0, done.stderr
    html = (tmp_path / "r.html").read_text()
    assert 'id="criticality"' in html and "worst long-tail scenario" in html


@pytest.mark.slow  # its module's fixture scores the demo's policies first (10 s): out of the fast tier
def test_no_analysis_leaves_the_official_fields_alone(runs, tmp_path):
    done = run_cli(
        "score",
        "--scenarios",
        *runs["scenarios"],
        "--submission",
        str(runs["idm"]),
        "--no-analysis",
        "-o",
        str(tmp_path / "plain.json"),
    )
    assert done.returncode == 0, done.stderr
    plain = json.loads((tmp_path / "plain.json").read_text())
    full = json.loads(runs["idm.json"].read_text())
    assert "analysis" not in plain and "analysis" in full
    analysis_fields = {"criticality", "driving", "by_object_type"}
    for row, full_row in zip(plain["scenarios"], full["scenarios"]):
        assert not analysis_fields & set(row)
        assert row == {k: v for k, v in full_row.items() if k not in analysis_fields}
    assert plain["buckets"] == full["buckets"] and plain["aggregate"] == full["aggregate"]
