"""`analysis.criticality_cache`: each scene's criticality kept between runs, the same results, never in the way."""

from __future__ import annotations

import csv
import json
import os
import sqlite3
import warnings

import pytest

from support.runs import run_cli
from wosac_eval.analysis import criticality_cache
from wosac_eval.analysis.criticality_cache import ENV, CriticalityCache, record_key
from wosac_eval.analysis.scenario_set_criticality import scenario_set_criticality
from wosac_eval.scoring.submission import score_submission
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import make_submission

# The scenes of tests/backends/score_backends_test.py's pipelined JAX run: the JAX test below compiles no
# program of its own (the buckets and batches of the same scenes are the same programs).
NUM_SCENES = 5


@pytest.fixture(scope="module")
def scene_set(tmp_path_factory):
    """Five demo-like scenes in two shards and an IDM submission of them."""
    root = tmp_path_factory.mktemp("criticality-cache")
    shards = scenes.write_scenario_shards(scenes.generate_scenes(NUM_SCENES, seed=0), root / "scenarios", 2)
    return [str(p) for p in shards], make_submission(shards, "idm", root / "idm", num_shards=2)


@pytest.fixture(scope="module")
def without_cache(scene_set):
    """The result document with no cache at all."""
    scenarios, submission = scene_set
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(ENV, "off")
        return as_json(score_submission(scenarios, submission))


def as_json(result: dict) -> dict:
    return json.loads(json.dumps(result))


def rows_in(path) -> list[tuple[str, str]]:
    with sqlite3.connect(path) as db:
        return db.execute("SELECT scenario_id, criticality FROM scenes ORDER BY scenario_id").fetchall()


def plant(path, braking: float) -> None:
    """Every kept scene's braking component set to `braking`: a value only the cache can give."""
    with sqlite3.connect(path) as db:
        for sid, text in db.execute("SELECT scenario_id, criticality FROM scenes").fetchall():
            row = json.loads(text)
            row["components"]["braking"] = braking
            db.execute("UPDATE scenes SET criticality = ? WHERE scenario_id = ?", (json.dumps(row), sid))


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_a_second_run_takes_every_scene_from_the_cache_and_writes_the_same_document(
    scene_set, without_cache, tmp_path, monkeypatch
):
    scenarios, submission = scene_set
    path = tmp_path / "cache" / "criticality.sqlite3"
    monkeypatch.setenv(ENV, str(path))
    assert as_json(score_submission(scenarios, submission)) == without_cache  # the run that fills it
    kept = rows_in(path)
    assert len(kept) == NUM_SCENES
    by_id = {row["scenario_id"]: row for row in without_cache["scenarios"]}
    for sid, text in kept:  # what was kept is what the row says (rarity is the set's, added later)
        assert json.loads(text)["components"].items() <= by_id[sid]["criticality"]["components"].items()
    assert as_json(score_submission(scenarios, submission)) == without_cache  # the run that reads it
    assert rows_in(path) == kept  # nothing computed again, so nothing written again
    plant(path, 0.123)
    planted = as_json(score_submission(scenarios, submission))
    assert {row["criticality"]["components"]["braking"] for row in planted["scenarios"]} == {0.123}
    # The set's ranking (`wosac-eval criticality`, `score --select`) reads the same rows.
    ranked = scenario_set_criticality(scenarios)
    assert {row["components"]["braking"] for row in ranked["scenarios"]} == {0.123}


def test_the_ranking_of_a_set_fills_the_cache_scoring_then_reads(scene_set, without_cache, tmp_path, monkeypatch):
    scenarios, submission = scene_set
    path = tmp_path / "criticality.sqlite3"
    monkeypatch.setenv(ENV, str(path))
    ranked = scenario_set_criticality(scenarios)
    assert len(rows_in(path)) == NUM_SCENES
    scored = {row["scenario_id"]: row["criticality"] for row in without_cache["scenarios"]}
    for row in ranked["scenarios"]:  # the same scores as the scored rows (rarity against the same set)
        assert row["score"] == scored[row["scenario_id"]]["score"]
    plant(path, 0.5)
    planted = as_json(score_submission(scenarios, submission))
    assert {row["criticality"]["components"]["braking"] for row in planted["scenarios"]} == {0.5}
    # Per-step values are computed, never taken from the cache (it keeps none).
    per_step = scenario_set_criticality(scenarios, per_step=True)
    assert all(row["components"]["braking"] != 0.5 and len(row["steps"]) == 91 for row in per_step["scenarios"])


@pytest.mark.jax
@pytest.mark.slow  # the JAX backend compiles its programs
def test_the_jax_backend_reads_and_fills_the_same_cache(scene_set, without_cache, tmp_path, monkeypatch):
    pytest.importorskip("jax")
    scenarios, submission = scene_set
    path = tmp_path / "criticality.sqlite3"
    monkeypatch.setenv(ENV, str(path))
    filled = as_json(score_submission(scenarios, submission, backend="jax"))
    assert len(rows_in(path)) == NUM_SCENES
    assert [row["criticality"] for row in filled["scenarios"]] == [
        row["criticality"] for row in without_cache["scenarios"]
    ]
    plant(path, 0.375)
    planted = as_json(score_submission(scenarios, submission, backend="jax"))
    assert {row["criticality"]["components"]["braking"] for row in planted["scenarios"]} == {0.375}


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_worker_processes_share_the_cache_on_the_command_line(scene_set, without_cache, tmp_path):
    scenarios, submission = scene_set
    path = tmp_path / "criticality.sqlite3"
    env = {**os.environ, ENV: str(path)}
    args = ("score", "--scenarios", *scenarios, "--submission", str(submission), "--workers", "2")
    for name in ("first", "again"):
        done = run_cli(*args, "-o", str(tmp_path / f"{name}.json"), env=env)
        assert done.returncode == 0, done.stderr
        result = json.loads((tmp_path / f"{name}.json").read_text())
        assert result["scenarios"] == without_cache["scenarios"], name
        assert len(rows_in(path)) == NUM_SCENES
    plant(path, 0.25)
    done = run_cli("criticality", "--scenarios", *scenarios, "-o", str(tmp_path / "c.csv"), env=env)
    assert done.returncode == 0, done.stderr
    assert {float(r["braking"]) for r in csv.DictReader((tmp_path / "c.csv").open())} == {0.25}


def test_a_changed_record_or_a_changed_formula_is_never_served_an_old_value(tmp_path):
    record = bytes(range(256)) * 8
    changed = record[:100] + bytes([record[100] ^ 1]) + record[101:]
    assert record_key("a", record) != record_key("a", changed)
    assert record_key("a", record) != record_key("b", record)
    path = tmp_path / "c.sqlite3"
    old, new = CriticalityCache(path, version="old"), CriticalityCache(path, version="new")
    old.put([(record_key("a", record), {"score": 1.0})])
    assert old.get(record_key("a", record)) == {"score": 1.0}
    assert old.get(record_key("a", changed)) is None
    assert new.get(record_key("a", record)) is None
    # The version is the code's: the modules that compute a scene's criticality, as installed.
    assert criticality_cache.code_version() == criticality_cache.code_version()
    assert len(criticality_cache.code_version()) == 16


def test_the_oldest_rows_go_past_the_bound(tmp_path, monkeypatch):
    monkeypatch.setattr(criticality_cache, "MAX_ROWS", 3)
    cache = CriticalityCache(tmp_path / "c.sqlite3", version="v")
    for k in range(5):
        cache.put([(record_key(f"s{k}", b"x"), {"k": k})])
    assert [cache.get(record_key(f"s{k}", b"x")) for k in range(5)] == [None, None, {"k": 2}, {"k": 3}, {"k": 4}]


@pytest.mark.parametrize("damage", ["not-a-folder", "not-a-database"])
def test_an_unusable_cache_warns_once_and_changes_no_result(scene_set, without_cache, tmp_path, monkeypatch, damage):
    scenarios, submission = scene_set
    if damage == "not-a-folder":
        (tmp_path / "file").write_text("a file where the cache's folder would be")
        path = tmp_path / "file" / "criticality.sqlite3"
    else:
        path = tmp_path / "criticality.sqlite3"
        path.write_bytes(b"these bytes are not an SQLite database, whatever the name says" * 100)
    monkeypatch.setenv(ENV, str(path))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert as_json(score_submission(scenarios, submission)) == without_cache
    said = [
        str(w.message)
        for w in caught
        if issubclass(w.category, RuntimeWarning) and "criticality cache" in str(w.message)
    ]
    assert len(said) == 1 and str(path) in said[0] and f"{ENV}=off" in said[0], said


def test_off_keeps_nothing(scene_set, tmp_path, monkeypatch):
    scenarios, submission = scene_set
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv(ENV, "off")
    score_submission(scenarios, submission)
    assert criticality_cache.cache_path() is None and not list(tmp_path.iterdir())
    monkeypatch.setenv(ENV, "")  # unset or empty: the user's cache folder
    assert criticality_cache.cache_path() == tmp_path / "wosac-eval" / "criticality.sqlite3"
