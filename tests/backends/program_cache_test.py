"""`--backend jax` programs kept between runs (`backends.program_cache`): read back, they give the same
features bit for bit; a damaged file, a feature from outside the package and the off switch fall back to
tracing. Each test has its own cache folder and starts with none of this process's programs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from support import golden
from wosac_eval.backends import jax_backend, program_cache
from wosac_eval.features import registry
from wosac_eval.features.metric_features import scenario_features

CASE_SET = golden.SETS[2]  # the oracle cases in the repository
CASE = CASE_SET.cases[0]


@pytest.fixture
def programs(tmp_path, monkeypatch):
    """A cache folder of this test's own, and this process's programs forgotten (as in a new process)."""
    folder = tmp_path / "programs"
    monkeypatch.setenv(program_cache.ENV, str(folder))
    monkeypatch.setattr(program_cache, "_programs", {})
    return folder


def _features():
    return jax_backend.scenarios_features([golden.inputs(CASE_SET, CASE)], challenge=CASE_SET.challenge)[0]


def _numpy():
    return golden.as_feature_dict(scenario_features(*golden.inputs(CASE_SET, CASE), challenge=CASE_SET.challenge))


def _files(folder):
    return sorted(folder.glob("*" + program_cache.SUFFIX))


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_a_kept_program_is_read_back_with_the_same_features(programs, monkeypatch):
    before = dict(program_cache.stats)
    golden.assert_features_equal(_features(), _numpy(), "traced and kept")
    (kept,) = _files(programs)
    assert program_cache.stats["written"] == before["written"] + 1

    monkeypatch.setattr(program_cache, "_programs", {})  # a later process: the program is read back
    golden.assert_features_equal(_features(), _numpy(), "read back")
    assert program_cache.stats["read"] == before["read"] + 1
    assert program_cache.stats["written"] == before["written"] + 1
    assert _files(programs) == [kept]


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_a_damaged_file_is_traced_anew_and_rewritten(programs, monkeypatch):
    _features()
    (kept,) = _files(programs)
    whole = kept.read_bytes()
    kept.write_bytes(whole[: len(whole) // 3])

    monkeypatch.setattr(program_cache, "_programs", {})
    monkeypatch.setattr(program_cache, "_warned", set())
    with pytest.warns(RuntimeWarning, match=f"{kept}.*traced anew"):
        features = _features()
    golden.assert_features_equal(features, _numpy(), "after a damaged file")
    assert kept.read_bytes() == whole


def step_length(context: registry.FeatureContext):
    """A kernel defined outside the package (the planar distance moved since the previous step)."""
    xp = context.xp
    x, y = (context.evaluated(context.traj[f]) for f in ("x", "y"))
    moved = xp.sqrt((x[..., 1:] - x[..., :-1]) ** 2 + (y[..., 1:] - y[..., :-1]) ** 2)
    return context.reported(xp.concatenate([xp.zeros_like(moved[..., :1]), moved], axis=-1))


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_a_feature_from_outside_the_package_is_never_kept(programs):
    assert program_cache.is_ours(registry.features()[0].kernel)
    assert not program_cache.is_ours(step_length)
    with registry.registered(registry.Feature("step_length_here", step_length)):
        log, sim = _features()
    assert np.asarray(sim.extra["step_length_here"]).shape == np.asarray(sim.linear_speed).shape
    assert _files(programs) == []


def test_off_traces_every_run(programs, monkeypatch):
    monkeypatch.setenv(program_cache.ENV, "off")
    golden.assert_features_equal(_features(), _numpy(), "cache off")
    assert not programs.exists()


def test_the_file_name_follows_the_static_facts_and_the_shapes():
    args = (np.zeros(2, np.int32), {"x": np.zeros((2, 3), np.float32)})
    name = program_cache.program_digest("features", "layout A", args)
    assert name == program_cache.program_digest("features", "layout A", args)
    assert name != program_cache.program_digest("features", "layout B", args)
    assert name != program_cache.program_digest("features", "layout A", (args[0], {"x": np.zeros((2, 4), np.float32)}))
    assert name != program_cache.program_digest("features", "layout A", (args[0], {"x": np.zeros((2, 3), np.float64)}))


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_the_code_version_follows_the_package_sources(tmp_path):
    """A copy of the package with one kernel changed has another code version (so its programs are new)."""
    import shutil

    package = tmp_path / "wosac_eval"
    shutil.copytree(Path(program_cache.__file__).parents[1], package, ignore=shutil.ignore_patterns("__pycache__"))
    version = "from wosac_eval.backends import program_cache as p; print(p.__file__); print(p.code_version())"

    def code_version():
        run = subprocess.run([sys.executable, "-c", version], cwd=tmp_path, capture_output=True, text=True, check=True)
        where, digest = run.stdout.split()
        assert Path(where).is_relative_to(package)  # the copy is the package measured
        return digest

    assert code_version() == program_cache.code_version()
    kernels = package / "features" / "kinematics.py"
    kernels.write_text(kernels.read_text() + "\n# changed\n")
    assert code_version() != program_cache.code_version()


@pytest.mark.slow  # two CLI runs, the first compiling for real: about 30 s on 2 cores
def test_the_cli_keeps_traced_and_compiled_programs_in_the_users_cache(tmp_path):
    """`wosac-eval score --backend jax` with nothing configured: the traced programs and XLA's compiled ones go
    to the user's cache folder, and a second run reads them back (no program written again) with the same
    result."""
    import os

    from support.paths import TEST_DATA
    from support.runs import run_cli

    case = "synthetic-7-000-collision__logreplay_noise05"
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", program_cache.ENV)}
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    home = tmp_path / "cache" / "wosac-eval"
    args = [
        "--scenarios",
        str(TEST_DATA / "oracle" / "scenes" / "collision.tfrecord"),
        "--submission",
        str(TEST_DATA / "oracle" / f"{case}.binproto.gz"),
    ]

    def score(name):
        out = tmp_path / name
        proc = run_cli("score", *args, "--backend", "jax", "-o", str(out), env=env)
        assert proc.returncode == 0, proc.stderr
        return json.loads(out.read_text())

    first = score("first.json")
    kept = {p.name: p.stat().st_ino for p in (home / "jax-programs").iterdir()}
    compiled = sorted(p.name for p in (home / "jax-compiled").iterdir())
    assert kept and compiled
    second = score("second.json")
    assert {p.name: p.stat().st_ino for p in (home / "jax-programs").iterdir()} == kept  # read, not rewritten
    assert sorted(p.name for p in (home / "jax-compiled").iterdir() if not p.name.endswith("-atime")) == [
        n for n in compiled if not n.endswith("-atime")
    ]
    assert second["scenarios"] == first["scenarios"] and second["aggregate"] == first["aggregate"]


def test_the_file_name_follows_x64():
    import jax

    args = (np.zeros(2, np.int32),)
    with jax.enable_x64(True):
        on = program_cache.program_digest("features", "layout A", args)
    assert on != program_cache.program_digest("features", "layout A", args)
