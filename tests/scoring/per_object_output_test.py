"""Per-object output of a scoring run (`score_submission(per_object=True)`, `score --per-object`).

On the demo's synthetic scenes (generated here, 6 scenes, two policies): every object's values equal
`score_scenario_per_object`'s, every scene field is the count-weighted geometric mean of its objects'
values, an interrupted and resumed run writes the same side file byte for byte, and a run without
`--per-object` is the same document as before (no key added).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from wosac_eval.arrays.object_types import SHORT_NAMES
from wosac_eval.fronts.cli import main
from wosac_eval.metrics.per_object import EVENTS
from wosac_eval.metrics.registry import LIKELIHOOD_FIELDS
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.parse.submission_source import find_scenario_rollouts
from wosac_eval.scoring.journal import ScoringJournal
from wosac_eval.scoring.objects import count_column, read_objects
from wosac_eval.scoring.scenario import score_scenario_per_object
from wosac_eval.scoring.submission import score_submission

SCENES = 6


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from wosac_eval.fronts.demo_pipeline import run_demo

    workdir = tmp_path_factory.mktemp("per-object-demo")
    run_demo(
        workdir,
        num_scenes=SCENES,
        policies=("constant_velocity", "idm"),
        challenge="sim_agents",
        log=lambda *a, **k: None,
    )
    return workdir / "scenarios", workdir / "submissions" / "idm.tar.gz"


@pytest.fixture(scope="module")
def scored(demo, tmp_path_factory):
    scenarios, submission = demo
    out = tmp_path_factory.mktemp("scored")
    result = score_submission([scenarios], submission, per_object=True, objects=out / "r.objects.jsonl")
    return result, out / "r.objects.jsonl"


def _by_scenario(path) -> dict[str, list[dict]]:
    grouped: dict[str, list[dict]] = {}
    for record in read_objects(path):
        grouped.setdefault(record["scenario_id"], []).append(record)
    return grouped


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_objects_equal_score_scenario_per_object(demo, scored):
    scenarios, submission = demo
    result, path = scored
    grouped = _by_scenario(path)
    ids = [row["scenario_id"] for row in result["scenarios"]]
    assert list(grouped) == ids  # the result's order
    assert result["per_object"] == {
        "objects": "r.objects.jsonl",
        "format": "jsonl",
        "num_objects": sum(map(len, grouped.values())),
    }
    index = ScenarioIndex([scenarios])
    rollouts = find_scenario_rollouts(submission, ids)
    for sid in ids:
        values = score_scenario_per_object(index.load(sid), rollouts[sid])
        records = grouped[sid]
        assert [r["object_id"] for r in records] == values.object_id.tolist()
        assert [r["object_type"] for r in records] == [SHORT_NAMES.get(t, "other") for t in values.object_type]
        for field in LIKELIHOOD_FIELDS:
            expected = values.likelihood[field].astype(np.float64)
            got = np.array([np.nan if r[field] is None else r[field] for r in records])
            np.testing.assert_array_equal(got, expected)
            assert [r[count_column(field)] for r in records] == values.count[field].tolist()
        for event in EVENTS:
            flags, first = values.flags[event], values.first_step[event]
            assert [r[f"{event}_rollouts"] for r in records] == flags.sum(axis=0).tolist()
            for k, r in enumerate(records):
                steps = first[flags[:, k], k]
                assert r[f"{event}_first_step"] == (int(steps.min()) if steps.size else None)
            assert all(r["num_rollouts"] == flags.shape[0] for r in records)


def test_scene_fields_are_count_weighted_geometric_means_of_the_objects(scored):
    result, path = scored
    grouped = _by_scenario(path)
    checked = 0
    for row in result["scenarios"]:
        for field in LIKELIHOOD_FIELDS:
            counted = [
                (r[count_column(field)], r[field]) for r in grouped[row["scenario_id"]] if r[count_column(field)] > 0
            ]
            if not counted:
                continue
            total = sum(c for c, _ in counted)
            mean = math.exp(sum(c * math.log(v) for c, v in counted) / total)
            assert mean == pytest.approx(row[field], rel=1e-6), (row["scenario_id"], field)
            checked += 1
    assert checked >= SCENES * 8


def test_inline_objects_and_parquet_hold_the_same_records(demo, scored, tmp_path):
    pytest.importorskip("pyarrow")
    scenarios, submission = demo
    result, path = scored
    records = list(read_objects(path))
    inline = score_submission([scenarios], submission, per_object=True)  # small sets: in the rows
    assert [o for row in inline["scenarios"] for o in row.pop("objects")] == records
    parquet = score_submission([scenarios], submission, per_object=True, objects=tmp_path / "r.objects.parquet")
    assert parquet["per_object"]["format"] == "parquet"
    assert list(read_objects(tmp_path / "r.objects.parquet")) == records
    for document in (inline, parquet):
        document.pop("per_object", None)
    plain = {k: v for k, v in result.items() if k != "per_object"}
    assert json.loads(json.dumps(inline)) == json.loads(json.dumps(plain))
    assert json.loads(json.dumps(parquet)) == json.loads(json.dumps(plain))


def test_resumed_run_writes_the_same_objects(demo, scored, tmp_path):
    scenarios, submission = demo
    result, path = scored
    journal = tmp_path / "run.journal"
    objects = tmp_path / "r.objects.jsonl"
    score_submission([scenarios], submission, journal=journal, per_object=True, objects=objects)
    assert objects.read_bytes() == path.read_bytes()
    lines = journal.read_bytes().splitlines(keepends=True)
    assert len(lines) == 1 + SCENES and all(b'"objects"' in line for line in lines[1:])
    journal.write_bytes(b"".join(lines[:3]) + lines[3][: len(lines[3]) // 2])  # as a kill leaves it
    identity = json.loads(lines[0])["run"]
    with ScoringJournal(journal, identity) as kept:  # the kept rows are held without their objects
        assert len(kept.done) == 2 and not any("objects" in row for row in kept.done.values())
        first = json.loads(lines[1])
        assert kept.objects_of(first["scenario_id"]) == first["objects"]
    objects.unlink()
    calls = []
    resumed = score_submission(
        [scenarios],
        submission,
        journal=journal,
        per_object=True,
        objects=objects,
        progress=lambda done, total: calls.append(done),
    )
    assert calls[0] == 2  # two rows were kept: not scored again
    assert objects.read_bytes() == path.read_bytes()
    assert json.loads(json.dumps(resumed)) == json.loads(json.dumps(result))
    # A journal without objects (a run without per_object) is another run's: set aside, not used.
    plain = tmp_path / "plain.journal"
    score_submission([scenarios], submission, journal=plain)
    again = score_submission([scenarios], submission, journal=plain, per_object=True, objects=objects)
    assert objects.read_bytes() == path.read_bytes() and again["per_object"] == result["per_object"]
    assert (tmp_path / "plain.journal.old").exists()


def test_cli_per_object_resumes_and_default_output_is_unchanged(demo, scored, tmp_path, capsys):
    scenarios, submission = demo
    result, path = scored
    output = tmp_path / "result.json"
    args = ["score", "--scenarios", str(scenarios), "--submission", str(submission), "-o", str(output)]
    assert main(args) == 0
    plain = output.read_text()
    assert '"per_object"' not in plain and '"objects"' not in plain
    assert main(args + ["--per-object"]) == 0
    side = tmp_path / "result.objects.jsonl"
    assert side.read_bytes() == path.read_bytes()
    document = json.loads(output.read_text())
    assert document.pop("per_object") == {
        "objects": side.name,
        "format": "jsonl",
        "num_objects": result["per_object"]["num_objects"],
    }
    assert document == json.loads(plain)
    assert not (tmp_path / "result.json.journal").exists()
    # Interrupted after two scenarios: the journal a kill leaves; the same command resumes.
    score_submission(
        [scenarios],
        submission,
        journal=tmp_path / "full.journal",
        per_object=True,
        objects=tmp_path / "scratch.objects.jsonl",
    )
    lines = (tmp_path / "full.journal").read_bytes().splitlines(keepends=True)
    (tmp_path / "result.json.journal").write_bytes(b"".join(lines[:3]))
    side.unlink()
    capsys.readouterr()
    assert main(args + ["--per-object"]) == 0
    assert "resuming from" in capsys.readouterr().err
    assert side.read_bytes() == path.read_bytes()
    assert json.loads(output.read_text())["per_object"]["num_objects"] == result["per_object"]["num_objects"]
    assert main(["score", "--scenarios", str(scenarios), "--submission", str(submission), "--per-object"]) == 2
    assert "--per-object needs --output" in capsys.readouterr().err
