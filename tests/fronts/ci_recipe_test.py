"""The CI recipe in examples/ci: the gate script run for real, and the workflow's structure."""

import json
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

from wosac_eval.fronts.cli import main

from support.paths import REPO, SHARED
from support.runs import WOSAC_EVAL

CI = REPO / "examples" / "ci"
SCENARIO = SHARED / "womd" / "motion_data_one_scenario.tfrecord"
GOLDEN = SHARED / "golden"


def _submission(policy: str) -> Path:
    if not SCENARIO.is_file() or not GOLDEN.is_dir():
        pytest.skip(f"reference material not found at {SHARED} (womd/ and golden/)")
    if shutil.which("bash") is None:
        pytest.skip("bash is not installed")
    return GOLDEN / f"637f20cafde22ff8__{policy}.binproto"


def _run_gate(tmp_path, submission, baseline, gates):
    summary = tmp_path / "summary.md"
    env = {
        "PATH": "/usr/bin:/bin",
        "WOSAC_EVAL": shlex.join(WOSAC_EVAL),
        "WOSAC_GATES": gates,
        "WOSAC_WORKERS": "1",
        "GITHUB_STEP_SUMMARY": str(summary),
    }
    proc = subprocess.run(
        ["bash", str(CI / "run_gate.sh"), str(submission), str(baseline), str(tmp_path / "out"), str(SCENARIO)],
        check=False,
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        cwd=tmp_path,
    )
    return proc, summary


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_gate_script_fails_on_a_regression_and_still_writes_the_report(tmp_path):
    baseline = tmp_path / "baseline.json"
    assert (
        main(
            [
                "score",
                "--scenarios",
                str(SCENARIO),
                "--submission",
                str(_submission("logreplay_noise05")),
                "--output",
                str(baseline),
            ]
        )
        == 0
    )
    # A stationary policy is metres away from the logged trajectories.
    proc, summary = _run_gate(tmp_path, _submission("stationary"), baseline, "metametric:0.5 min_ade:1.0")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "gate min_average_displacement_error:1  FAIL" in proc.stdout
    assert "gate metametric:0.5  PASS" in proc.stdout
    assert "a regression gate failed" in proc.stderr
    out = tmp_path / "out"
    comparison = json.loads((out / "comparison.json").read_text())
    assert comparison["passed"] is False and comparison["scenarios"]["shared"] == 1
    assert (out / "comparison.txt").read_text() in proc.stdout
    assert 'id="comparison"' in (out / "report.html").read_text()
    text = summary.read_text()  # the Markdown table, in the GitHub job summary
    assert "### WOSAC realism" in text and "**gate failed**" in text
    assert (
        "| `min_average_displacement_error` | lower |" in text and "**FAIL** `min_average_displacement_error:1`" in text
    )


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_gate_script_without_baseline_scores_and_reports(tmp_path):
    proc, summary = _run_gate(tmp_path, _submission("logreplay_noise05"), tmp_path / "missing.json", "metametric:0.005")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "no baseline" in proc.stdout
    assert json.loads((tmp_path / "out" / "new.json").read_text())["scenarios"][0]["scenario_id"] == "637f20cafde22ff8"
    assert 'id="headline"' in (tmp_path / "out" / "report.html").read_text()
    assert "No baseline yet" in summary.read_text()


def test_gate_script_usage_error():
    proc = subprocess.run(
        ["bash", str(CI / "run_gate.sh"), "only-one-arg"], check=False, capture_output=True, text=True
    )
    assert proc.returncode == 2 and "usage:" in proc.stderr


def test_workflow_runs_the_gate_script():
    yaml = pytest.importorskip("yaml")
    workflow = yaml.safe_load((CI / "wosac-realism.yml").read_text())
    steps = workflow["jobs"]["realism"]["steps"]
    commands = "\n".join(s.get("run", "") for s in steps)
    assert "pip install wosac-eval" in commands
    assert "bash ci/run_gate.sh submission.tar.gz" in commands
    assert "WOSAC_GATES" in workflow["env"] and "metametric:" in workflow["env"]["WOSAC_GATES"]
    upload = next(s for s in steps if s.get("uses", "").startswith("actions/upload-artifact"))
    assert upload["if"] == "${{ !cancelled() }}"  # the report is uploaded when the gate fails
    assert set(workflow[True]) >= {"pull_request", "push"}  # YAML 1.1 reads the key `on` as True
