"""score -> compare -> report on real WOMD data and real submissions, through the CLI."""

import json
from pathlib import Path

import pytest

from wosac_eval.fronts.cli import main

from support.paths import SHARED

SCENARIO = SHARED / "womd" / "motion_data_one_scenario.tfrecord"
GOLDEN = SHARED / "golden"


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    if not SCENARIO.is_file() or not GOLDEN.is_dir():
        pytest.skip(f"reference material not found at {SHARED} (womd/ and golden/)")
    out = tmp_path_factory.mktemp("scored")
    paths = {}
    for policy in ("logreplay_noise05", "stationary"):
        paths[policy] = out / f"{policy}.json"
        code = main(
            [
                "score",
                "--scenarios",
                str(SCENARIO),
                "--submission",
                str(GOLDEN / f"637f20cafde22ff8__{policy}.binproto"),
                "--output",
                str(paths[policy]),
            ]
        )
        assert code == 0
    return paths


def test_compare_real_results_gates_on_min_ade(scored, capsys):
    base, new = str(scored["logreplay_noise05"]), str(scored["stationary"])
    capsys.readouterr()
    # A stationary policy is metres off the logged trajectories: the minADE gate must fail.
    assert main(["compare", base, new, "--json", "--fail-if-worse", "min_ade:1.0"]) == 1
    out = json.loads(capsys.readouterr().out)
    golden = {
        p: json.loads((GOLDEN / f"637f20cafde22ff8__{p}.json").read_text())["metrics"]["2025"]
        for p in ("logreplay_noise05", "stationary")
    }
    min_ade = next(m for m in out["metrics"] if m["metric"] == "min_average_displacement_error")
    expected = (
        golden["stationary"]["min_average_displacement_error"]
        - golden["logreplay_noise05"]["min_average_displacement_error"]
    )
    assert min_ade["difference"] == pytest.approx(expected, rel=1e-4)
    # One shared scenario: both sign patterns give the same |mean|, so nothing can be significant.
    assert out["scenarios"]["shared"] == 1 and min_ade["p_value"] == 1.0
    assert min_ade["verdict"] == "no significant difference"
    assert any("only 1 shared scenarios" in w for w in out["warnings"])
    # The buckets are per-scenario (weights from the config) and match the official buckets.
    inter = next(m for m in out["metrics"] if m["metric"] == "interactive_metrics")
    assert inter["paired"] and inter["new"] == pytest.approx(
        golden["stationary"]["buckets"]["interactive_metrics"], abs=1e-4
    )


def test_report_on_real_results(scored, tmp_path):
    html_path = tmp_path / "report.html"
    assert (
        main(
            [
                "report",
                str(scored["stationary"]),
                "--compare",
                str(scored["logreplay_noise05"]),
                "--html",
                str(html_path),
            ]
        )
        == 0
    )
    page = html_path.read_text()
    assert "637f20cafde22ff8" in page and 'id="comparison"' in page
