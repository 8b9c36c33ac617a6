"""The command line meets mistakes as a new user makes them: one clear line, the right exit code, no traceback.

Every case runs the real `wosac-eval` in a subprocess on real files (synthetic
scenes and a real baseline submission; the official test submission where the
reference material is present).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path, PurePosixPath

import pytest

from wosac_eval.parse.shard_walk import iter_submission_shards

from support.paths import REPO, require_shared
from support.runs import WOSAC_EVAL, run_cli


@pytest.fixture(scope="module")
def scene_and_submission(tmp_path_factory):
    """Two synthetic scenes (one TFRecord) and a valid constant-velocity submission (.tar.gz)."""
    from wosac_eval.sim import scenes
    from wosac_eval.sim.baselines import make_submission

    folder = tmp_path_factory.mktemp("cli")
    paths = scenes.write_scenario_shards(scenes.generate_scenes(2, seed=5), folder / "scenarios", num_shards=1)
    submission = make_submission(paths, "constant_velocity", folder / "cv.tar.gz", num_shards=1)
    return paths[0], submission


def assert_one_clean_error(proc: subprocess.CompletedProcess, *expected: str) -> None:
    """Exit 2, no traceback, and the message names what it must."""
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    for text in expected:
        assert text in proc.stderr, proc.stderr


def test_version():
    import wosac_eval

    proc = run_cli("--version")
    assert proc.returncode == 0
    assert proc.stdout.strip().startswith(f"wosac-eval {wosac_eval.__version__} ")


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_unwritable_output_is_refused_before_any_work(tmp_path, scene_and_submission):
    scenarios, submission = scene_and_submission
    missing = tmp_path / "missing" / "r.json"
    proc = run_cli("score", "--scenarios", str(scenarios), "--submission", str(submission), "-o", str(missing))
    assert_one_clean_error(proc, "--output", str(missing.parent), "does not exist")
    assert "scored" not in proc.stderr  # refused before scoring, not after
    proc = run_cli("score", "--scenarios", str(scenarios), "--submission", str(submission), "-o", str(tmp_path))
    assert_one_clean_error(proc, "is a folder")


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_other_outputs_are_checked_first(tmp_path, scene_and_submission):
    scenarios, _ = scene_and_submission
    nowhere = tmp_path / "nowhere"
    (tmp_path / "file.txt").write_text("")
    proc = run_cli(
        "baseline",
        "--scenarios",
        str(scenarios),
        "--policy",
        "idm",
        "--output",
        str(tmp_path / "file.txt" / "sub.tar.gz"),
        cwd=tmp_path,
    )
    assert_one_clean_error(proc, "file.txt")
    demo = run_cli("demo", "--gate", str(tmp_path / "gate"), cwd=tmp_path)
    assert demo.returncode == 0, demo.stderr
    base, new = tmp_path / "gate" / "baseline.json", tmp_path / "gate" / "new.json"
    proc = run_cli("report", str(new), "--html", str(nowhere / "r.html"))
    assert_one_clean_error(proc, "--html", "does not exist")
    proc = run_cli("compare", str(base), str(new), "--markdown-output", str(nowhere / "c.md"))
    assert_one_clean_error(proc, "--markdown-output", "does not exist")


def test_compare_on_a_binary_file_names_it(tmp_path, scene_and_submission):
    _, submission = scene_and_submission
    result = tmp_path / "r.json"
    result.write_text("{}")
    proc = run_cli("compare", str(submission), str(result))
    assert_one_clean_error(proc, str(submission), "binary file", "wosac-eval score --output")


def test_output_into_a_closed_pipe_ends_quietly(scene_and_submission):
    scenarios, submission = scene_and_submission
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone, as after `| head` has read its lines
    try:
        proc = subprocess.run(
            [
                *WOSAC_EVAL,
                "validate",
                "--scenarios",
                str(scenarios),
                "--submission",
                str(submission),
                "--json",
            ],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            cwd=REPO,
            timeout=300,
        )
    finally:
        os.close(write_end)
    assert proc.returncode == 141, proc.stderr
    assert proc.stderr == ""


def test_swapped_scenarios_and_submission_get_a_hint(scene_and_submission):
    scenarios, submission = scene_and_submission
    for command in ("score", "validate"):
        proc = run_cli(command, "--scenarios", str(submission), "--submission", str(scenarios))
        assert_one_clean_error(proc, "swapped")


def test_a_truncated_shard_is_called_truncated(tmp_path, scene_and_submission):
    scenarios, submission = scene_and_submission
    # The first shard of the archive, cut short (tarfile's extraction filters are missing from some
    # patched interpreters, Debian 12's python3.11 among them: the project's reader needs none).
    name, data = next(iter_submission_shards(submission))
    shard = tmp_path / PurePosixPath(name).name
    shard.write_bytes(data[: len(data) * 2 // 3])
    proc = run_cli("validate", "--scenarios", str(scenarios), "--submission", str(shard))
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "truncated" in proc.stdout and "cut short" in proc.stdout


def test_archive_bytes_given_as_a_shard_are_recognised(tmp_path, scene_and_submission):
    scenarios, submission = scene_and_submission
    disguised = tmp_path / "sub.binproto"
    disguised.write_bytes(submission.read_bytes())
    proc = run_cli("validate", "--scenarios", str(scenarios), "--submission", str(disguised))
    assert proc.returncode == 0, proc.stdout  # read as what it is, with a warning about the name
    assert "the name does not say so, but this is a gzip-compressed tar" in proc.stdout


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_official_test_submission_scores_with_metadata_warnings(tmp_path):
    """The official test submission has no account or flags: local scoring lists them, validate refuses."""
    shared = require_shared("womd")
    args = [
        "--scenarios",
        str(shared / "womd" / "motion_data_one_scenario.tfrecord"),
        "--submission",
        str(shared / "womd" / "test_submission.binproto"),
    ]
    out = tmp_path / "r.json"
    proc = run_cli("score", *args, "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "warning: metadata.missing" in proc.stderr and "uses_lidar_data" in proc.stderr
    assert "warning: metadata.invalid" in proc.stderr and "account_name" in proc.stderr
    result = json.loads(out.read_text())
    assert result["validation"]["errors"] == 0 and result["coverage"]["fraction"] == 1.0
    codes = {g["code"]: g for g in result["validation"]["findings"]}
    assert codes["metadata.missing"]["severity"] == "warning" and codes["metadata.missing"]["count"] == 5
    strict = run_cli("score", *args, "-o", str(out), "--strict-metadata")
    assert strict.returncode == 1 and "metadata.missing" in strict.stderr
    check = run_cli("validate", *args)
    assert check.returncode == 1 and "ERROR metadata.missing" in check.stdout


def test_partial_scoring_states_its_coverage(tmp_path):
    shared = require_shared("womd")
    out = tmp_path / "r.json"
    proc = run_cli(
        "score",
        "--scenarios",
        str(shared / "womd"),
        "--submission",
        str(shared / "womd" / "test_submission.binproto"),
        "--partial",
        "-o",
        str(out),
    )
    assert proc.returncode == 0, proc.stderr
    assert "partial result: scored 1 of 2 scenario(s) (50.0%)" in proc.stderr
    assert json.loads(out.read_text())["coverage"] == {"scored": 1, "expected": 2, "fraction": 0.5}


def test_interrupt_ends_with_130_and_no_traceback(tmp_path):
    """Ctrl-C during the demo: one line, exit 130; the demo's first progress line comes at once."""
    # Ctrl-C as at a terminal: a test run started in the background of a shell inherits SIGINT ignored,
    # and Python then never raises KeyboardInterrupt; the command itself runs as `python -m`.
    as_at_a_terminal = (
        "import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
        "sys.argv[0] = 'wosac-eval'; runpy.run_module('wosac_eval.fronts.cli', run_name='__main__')"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", as_at_a_terminal, "demo", "--workdir", str(tmp_path / "demo"), "--workers", "1"],
        cwd=tmp_path,  # not the repository: `-c` imports from its working folder
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        first = proc.stdout.readline()  # flushed before any scene is generated
        assert first.startswith("sim_agents: 3 policies on 10 synthetic scenes"), first
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err


def test_an_internal_error_is_one_line_unless_debugging(monkeypatch, capsys):
    """A bug inside a command: its type and message, a request to report it, exit 2; the traceback on demand."""
    from wosac_eval.fronts import cli
    from wosac_eval.fronts.commands import report

    def broken(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(report, "run", broken)
    monkeypatch.delenv("WOSAC_EVAL_DEBUG", raising=False)
    assert cli.main(["report", "r.json", "--html", "r.html"]) == 2
    err = capsys.readouterr().err
    assert "internal error: RuntimeError: a bug" in err and "WOSAC_EVAL_DEBUG=1" in err
    monkeypatch.setenv("WOSAC_EVAL_DEBUG", "1")
    with pytest.raises(RuntimeError, match="a bug"):
        cli.main(["report", "r.json", "--html", "r.html"])


def test_report_legend_covers_no_bar(tmp_path):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from wosac_eval.results.report_plots import bucket_figure
    from wosac_eval.scoring.result_reader import load_result
    from wosac_eval.results.synthetic_results import write_gate_demo_results

    base_path, new_path = write_gate_demo_results(tmp_path, num_scenarios=50)
    fig = bucket_figure(load_result(new_path), load_result(base_path))
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    ax = fig.axes[0]
    legend = ax.get_legend().get_window_extent(renderer)
    bars = [patch.get_window_extent(renderer) for patch in ax.patches]
    labels = [text.get_window_extent(renderer) for text in ax.texts]
    assert bars and labels
    assert not any(legend.overlaps(box) for box in bars + labels)


def test_criticality_output_that_cannot_be_created_is_refused_up_front(scene_and_submission):
    # /proc passes every permission check a root user makes, yet takes no new file: refused before the work.
    scenarios, _ = scene_and_submission
    proc = run_cli("criticality", "--scenarios", str(scenarios), "-o", "/proc/r.json")
    assert_one_clean_error(proc, "--output /proc/r.json: cannot write: cannot create a file in /proc")
    assert "internal error" not in proc.stderr and "scenario(s)" not in proc.stdout
    assert not Path("/proc/r.json").exists()


def test_criticality_with_a_ray_cluster_that_is_not_there(scene_and_submission):
    pytest.importorskip("ray", reason="the ray extra is not installed: --engine ray stops at the install hint")
    scenarios, _ = scene_and_submission
    proc = run_cli("criticality", "--scenarios", str(scenarios), "--engine", "ray", "--ray-address", "127.0.0.1:9")
    assert_one_clean_error(proc, "cannot reach the Ray cluster at 127.0.0.1:9")
    assert "internal error" not in proc.stderr


def test_score_with_a_binary_config_names_the_file(tmp_path, scene_and_submission):
    scenarios, submission = scene_and_submission
    config = tmp_path / "config.textproto"
    config.write_bytes(b"metric \xff\xfe\x00\x01 binary")
    proc = run_cli("score", "--scenarios", str(scenarios), "--submission", str(submission), "--config", str(config))
    assert_one_clean_error(proc, f"{config}: not a SimAgentMetricsConfig textproto: not UTF-8 text (byte 7 is 0xff)")
    assert "codec" not in proc.stderr


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_a_command_loads_only_its_own_modules():
    """`wosac-eval compare` and `report` read result files: they start without the scoring stack, which
    `score` loads; `--help` still lists every command."""
    from wosac_eval.fronts import cli

    for name in cli.command_names():
        assert __import__(f"wosac_eval.fronts.commands.{name}", fromlist=["NAME"]).NAME == name
    probe = (
        "import sys; from wosac_eval.fronts import cli; sys.argv = ['wosac-eval', '{0}', '--help']\n"
        "try: cli.main()\nexcept SystemExit: pass\n"
        "print('wosac_eval.scoring.submission' in sys.modules)"
    )
    for name, loaded in (("compare", "False"), ("report", "False"), ("score", "True")):
        done = subprocess.run([sys.executable, "-c", probe.format(name)], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        assert f"usage: wosac-eval {name}" in done.stdout and done.stdout.splitlines()[-1] == loaded, done.stdout
    listing = run_cli("--help")
    assert listing.returncode == 0 and all(name in listing.stdout for name in cli.command_names())
