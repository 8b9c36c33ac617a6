"""The options several commands share are declared once (`fronts/usage.py`), each with the one type that
checks it: a bad value gets the same one-line refusal from every command, before any work, and the same
option means the same thing everywhere (`score --max-bytes` is the limit `validate --max-bytes` applies)."""

from __future__ import annotations

import argparse
import importlib
import json

import pytest

from support.runs import run_cli
from wosac_eval.fronts import cli, usage
from wosac_eval.parse.limits import InputLimits

WORKERS = ("baseline", "criticality", "demo", "score", "validate")
SCENARIOS = ("baseline", "criticality", "plot", "report", "score", "validate")
ENGINE = ("criticality", "score", "validate")
LIMITS = ("score", "validate")


def _parser(command: str) -> argparse.ArgumentParser:
    """The command's own parser, as the command line builds it."""
    parser = argparse.ArgumentParser(prog=f"wosac-eval {command}")
    importlib.import_module(f"wosac_eval.fronts.commands.{command}").add_arguments(parser)
    return parser


def test_each_command_has_the_shared_options_it_should_with_their_one_meaning():
    for command in cli.command_names():
        parser = _parser(command)
        shown = parser.format_help()
        assert ("--workers N" in shown) == (command in WORKERS), command
        assert ("--scenarios PATH [PATH ...]" in shown) == (command in SCENARIOS), command
        assert ("--engine {local,ray}" in shown) == ("--ray-address ADDR" in shown) == (command in ENGINE), command
        assert ("--max-bytes SIZE" in shown) == ("--max-shard-bytes SIZE" in shown) == (command in LIMITS), command
        if command in LIMITS:
            assert parser.get_default("max_bytes") == InputLimits.max_total_bytes
            assert parser.get_default("max_shard_bytes") == InputLimits.max_member_bytes
            assert "(default 256G)" in " ".join(shown.split())  # the real default, not a stale figure
        if command in WORKERS:
            assert parser.get_default("workers") >= 1


@pytest.mark.parametrize("command", WORKERS)
@pytest.mark.parametrize(("value", "said"), [("0", "'0': give at least 1 process"), ("two", "'two' is not a whole")])
def test_a_bad_worker_count_is_refused_by_every_command_alike(command, value, said, capsys):
    with pytest.raises(SystemExit) as exited:
        cli.main([command, "--workers", value])
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert f"wosac-eval {command}: error: argument --workers: {said}" in err
    assert "Traceback" not in err


def test_the_refusal_is_one_line_of_the_real_command():
    proc = run_cli("score", "--scenarios", "x", "--submission", "y", "--workers", "-1")
    assert proc.returncode == 2
    assert proc.stderr.splitlines()[-1] == "wosac-eval score: error: argument --workers: '-1': give at least 1 process"


@pytest.mark.parametrize(
    ("text", "size"), [("4096", 4096), ("512K", 512 << 10), ("1.5TiB", 3 << 39), ("64m", 64 << 20)]
)
def test_sizes_in_bytes(text, size):
    assert usage.size_in_bytes(text) == size


@pytest.mark.parametrize("text", ["0", "lots", "-1G", "0.1"])
def test_a_size_that_is_not_one_is_refused(text):
    with pytest.raises(argparse.ArgumentTypeError, match=repr(text)):
        usage.size_in_bytes(text)


@pytest.fixture(scope="module")
def scene_and_submission(tmp_path_factory):
    """Two synthetic scenes and a valid constant-velocity submission (.tar.gz)."""
    from wosac_eval.sim import scenes
    from wosac_eval.sim.baselines import make_submission

    folder = tmp_path_factory.mktemp("limits")
    paths = scenes.write_scenario_shards(scenes.generate_scenes(2, seed=5), folder / "scenarios", num_shards=1)
    return paths[0], make_submission(paths, "constant_velocity", folder / "cv.tar.gz", num_shards=1)


@pytest.mark.parametrize(
    ("option", "said"),
    [
        ("--max-bytes", f"more than the total limit of {64 << 10} bytes"),
        ("--max-shard-bytes", f"over the per-member limit of {64 << 10} bytes"),
    ],
)
def test_score_applies_the_input_limits_validate_applies(tmp_path, capsys, scene_and_submission, option, said):
    """The same submission over the same limit: `validate` and `score` refuse it with the same finding."""
    scenarios, submission = scene_and_submission
    inputs = ["--scenarios", str(scenarios), "--submission", str(submission), option, "64K"]
    assert cli.main(["validate", *inputs]) == 1
    validated = capsys.readouterr().out
    assert cli.main(["score", *inputs, "-o", str(tmp_path / "result.json")]) == 1
    scored = capsys.readouterr().err
    finding = next(line for line in validated.splitlines() if said in line)
    assert finding in scored
    assert not (tmp_path / "result.json").exists()
    assert cli.main(["score", *inputs[:4], "-o", str(tmp_path / "result.json")]) == 0  # the defaults let it through
    assert json.loads((tmp_path / "result.json").read_text())["num_scenarios"] == 2
