"""Tests of the demo's scene cache and leaderboard table."""

from __future__ import annotations

import json
from pathlib import Path

from wosac_eval.fronts import demo_pipeline
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.sim import scenes


def test_scenes_are_generated_once_then_loaded(tmp_path):
    paths, fresh = demo_pipeline.ensure_scenes(tmp_path, num_scenes=2, seed=4)
    assert fresh and [p.name for p in paths] == [
        "synthetic.tfrecord-00000-of-00002",
        "synthetic.tfrecord-00001-of-00002",
    ]
    manifest = json.loads((tmp_path / "scenarios" / "manifest.json").read_text())
    expected = scenes.generate_scenes(2, seed=4)
    assert manifest["sha256"] == scenes.scenario_fingerprint(expected)
    assert sorted(s.scenario.scenario_id for s in iter_scenarios(paths)) == sorted(s.scenario_id for s in expected)
    mtimes = [p.stat().st_mtime_ns for p in paths]
    again, fresh = demo_pipeline.ensure_scenes(tmp_path, num_scenes=2, seed=4)
    assert not fresh and again == paths and [p.stat().st_mtime_ns for p in again] == mtimes


def test_scenes_are_regenerated_when_the_request_or_the_cache_changes(tmp_path):
    demo_pipeline.ensure_scenes(tmp_path, num_scenes=2, seed=4)
    _, fresh = demo_pipeline.ensure_scenes(tmp_path, num_scenes=3, seed=4)
    assert fresh
    assert len(list((tmp_path / "scenarios").glob("synthetic.tfrecord-*"))) == 2  # old shards removed
    next((tmp_path / "scenarios").glob("synthetic.tfrecord-*")).unlink()
    _, fresh = demo_pipeline.ensure_scenes(tmp_path, num_scenes=3, seed=4)
    assert fresh
    (tmp_path / "scenarios" / "manifest.json").write_text("{not json")
    paths, fresh = demo_pipeline.ensure_scenes(tmp_path, num_scenes=3, seed=4)
    assert fresh and all(p.exists() for p in paths)


def test_leaderboard_orders_by_meta_metric_and_marks_invalid_rows():
    def row(policy, meta, valid=True):
        buckets = {key: meta for key, _ in demo_pipeline.BUCKETS}
        return demo_pipeline.PolicyResult(policy, Path("s"), Path("r"), buckets if valid else {}, valid, 0.0)

    table = demo_pipeline.leaderboard([row("b", 0.5), row("a", 0.75), row("broken", 0.0, valid=False)])
    lines = table.splitlines()
    assert lines[0].split()[:2] == ["policy", "meta"]
    assert [line.split()[0] for line in lines[2:]] == ["a", "b", "broken"]
    assert lines[2].split()[1] == "0.7500" and "invalid" in lines[4]
