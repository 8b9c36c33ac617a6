"""End-to-end tests of `wosac-eval demo` and `wosac-eval baseline`, run as real subprocesses."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from support.runs import WOSAC_EVAL


def cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*WOSAC_EVAL, *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_demo_runs_end_to_end_and_ranks_the_baselines(tmp_path):
    workdir = tmp_path / "demo"
    done = cli("demo", "--workdir", str(workdir), "--scenes", "3", "--workers", "2", cwd=tmp_path)
    assert done.returncode == 0, done.stderr + done.stdout
    out = done.stdout
    assert "generated 3 synthetic scenes" in out
    lines = out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("policy"))
    assert "meta" in lines[header] and "collision" in lines[header] and "red-light" in lines[header]
    ranked = [lines[header + 2 + k].split()[0] for k in range(3)]
    assert ranked[0] == "log_replay_noise" and ranked[-1] == "constant_velocity", out
    metas = {}
    for policy in ("log_replay_noise", "idm", "constant_velocity"):
        result = json.loads((workdir / "results" / f"{policy}.json").read_text())
        assert result["num_scenarios"] == 3 and result["validation"]["errors"] == 0
        metas[policy] = result["buckets"]["realism_meta_metric"]
        assert str(workdir / "results" / f"{policy}.json") in out
        assert (workdir / "submissions" / f"{policy}.tar.gz").exists()
    assert metas["log_replay_noise"] > metas["idm"] > metas["constant_velocity"]
    # A second run reuses the cached scenes and gives the same numbers.
    again = cli(
        "demo",
        "--workdir",
        str(workdir),
        "--scenes",
        "3",
        "--policies",
        "constant_velocity",
        "--workers",
        "1",
        cwd=tmp_path,
    )
    assert again.returncode == 0, again.stderr
    assert "loaded 3 synthetic scenes" in again.stdout
    result = json.loads((workdir / "results" / "constant_velocity.json").read_text())
    assert result["buckets"]["realism_meta_metric"] == metas["constant_velocity"]


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_baseline_command_writes_a_valid_submission(tmp_path):
    from wosac_eval.sim import scenes

    paths = scenes.write_scenario_shards(scenes.generate_scenes(2, seed=3), tmp_path / "scenarios", 2)
    out = tmp_path / "sub" / "idm.tar.gz"
    done = cli(
        "baseline",
        "--scenarios",
        str(paths[0].parent),
        "--policy",
        "idm",
        "--output",
        str(out),
        "--method-name",
        "my-idm",
        "--shards",
        "2",
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert "validation: ok" in done.stdout and out.exists()
    check = cli("validate", "--scenarios", *map(str, paths), "--submission", str(out), cwd=tmp_path)
    assert check.returncode == 0, check.stdout + check.stderr


@pytest.mark.parametrize(
    "args",
    [
        ("--policy", "teleport"),
        ("--policy", "idm", "--shards", "0"),
    ],
)
def test_baseline_usage_errors_exit_2(tmp_path, args):
    from wosac_eval.sim import scenes

    paths = scenes.write_scenario_shards(scenes.generate_scenes(1, seed=3), tmp_path, 1)
    done = cli("baseline", "--scenarios", str(paths[0]), "--output", str(tmp_path / "x.tar.gz"), *args, cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr


def test_baseline_missing_scenarios_exit_2_with_the_path(tmp_path):
    missing = tmp_path / "nope.tfrecord"
    done = cli(
        "baseline", "--scenarios", str(missing), "--policy", "idm", "--output", str(tmp_path / "x.tar.gz"), cwd=tmp_path
    )
    assert done.returncode == 2
    assert "nope.tfrecord" in done.stderr
