"""Result documents carry `schema_version`; the reader reads every earlier version and refuses a newer one.

`tests/data/results/schema_v1_result.json` is a document of version 1 (written before the field), saved
from `wosac-eval score` of two oracle scenes (its README says how).
"""

from __future__ import annotations

import copy
import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from wosac_eval.fronts.cli import main
from wosac_eval.scoring import result_reader
from wosac_eval.scoring.result_reader import (
    SCHEMA_VERSION,
    SCENARIO_FIELDS,
    VERSION_FIELDS,
    ResultError,
    load_result,
    parse_result,
)
from wosac_eval.scoring.submission import score_submission

DATA = Path(__file__).resolve().parents[1] / "data"
SAVED_V1 = DATA / "results" / "schema_v1_result.json"
CASES = (
    ("red_light", "synthetic-7-000-red-light__constvel_noise"),
    ("offroad", "synthetic-7-000-offroad__logreplay_noise05"),
)


def _saved() -> dict:
    return json.loads(SAVED_V1.read_text())


def _write(path: Path, document: dict) -> Path:
    path.write_text(json.dumps(document, indent=1))
    return path


def test_a_saved_version_1_document_is_read_as_written():
    document = _saved()
    assert "schema_version" not in document
    result = load_result(SAVED_V1)
    assert result.schema_version == 1 and result.config == "2025" and result.challenge == "sim_agents"
    assert list(result.scenario_ids) == [row["scenario_id"] for row in document["scenarios"]]
    for field in VERSION_FIELDS[1]:
        assert result.values[field].tolist() == [row[field] for row in document["scenarios"]], field
    assert result.buckets == document["buckets"]
    # The rows carry no buckets: they are recomputed from the config's weights, and their mean is the file's.
    for bucket in ("kinematic_metrics", "interactive_metrics", "map_based_metrics"):
        assert result.values[bucket].mean() == pytest.approx(document["buckets"][bucket], abs=1e-6)
    assert result.criticality is not None and set(result.by_type) >= {"vehicle"}


def _same_document(today, saved, where: str = "") -> None:
    """The same keys in the same order and the same values, but wosac-eval's own float64 diagnostics
    (criticality, realism per type) within 4 units in the last place: they call numpy's float64 `exp`
    and `log`, whose vectorised code depends on the CPU (AVX-512 or not) in the last bit."""
    if isinstance(saved, dict):
        assert list(today) == list(saved), where
        for key in saved:
            _same_document(today[key], saved[key], f"{where}.{key}")
    elif isinstance(saved, list):
        assert len(today) == len(saved), where
        for k, (a, b) in enumerate(zip(today, saved)):
            _same_document(a, b, f"{where}[{k}]")
    elif isinstance(saved, float) and (".criticality" in where or ".by_object_type" in where):
        np.testing.assert_array_max_ulp(np.float64(today), np.float64(saved), maxulp=4)
    else:
        assert today == saved, where


def test_todays_score_writes_the_saved_document_with_its_version(tmp_path):
    shards = tmp_path / "submission"
    shards.mkdir()
    for k, (_, case) in enumerate(CASES):
        data = gzip.decompress((DATA / "oracle" / f"{case}.binproto.gz").read_bytes())
        (shards / f"submission.binproto-{k:05d}-of-{len(CASES):05d}").write_bytes(data)
    scenes = [DATA / "oracle" / "scenes" / f"{scene}.tfrecord" for scene, _ in CASES]
    today = json.loads(json.dumps(score_submission(scenes, shards)))
    assert list(today)[0] == "schema_version" and today["schema_version"] == SCHEMA_VERSION == 2
    del today["schema_version"]
    _same_document(today, _saved())  # version 2 is version 1 with the field recorded
    assert parse_result(json.loads(json.dumps({"schema_version": 2, **today}))).schema_version == 2
    # Its official fields are the official implementation's, bit for bit (the oracle cases' outputs).
    for row, (_, case) in zip(today["scenarios"], CASES):
        official = json.loads((DATA / "oracle" / f"{case}.json").read_text())["metrics"]["2025"]
        for field, value in official.items():
            if field != "buckets":
                assert row[field] == value, (case, field)


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_compare_and_report_read_a_saved_document_beside_a_current_one(tmp_path, capsys):
    current = _write(tmp_path / "current.json", {"schema_version": SCHEMA_VERSION, **_saved()})
    assert main(["compare", str(SAVED_V1), str(current), "--n-boot", "200", "--n-perm", "200"]) == 0
    out = capsys.readouterr().out
    assert "realism_meta_metric" in out or "metametric" in out
    page = tmp_path / "report.html"
    assert (
        main(
            [
                "report",
                str(current),
                "--compare",
                str(SAVED_V1),
                "--html",
                str(page),
                "--n-boot",
                "200",
                "--n-perm",
                "200",
            ]
        )
        == 0
    )
    assert "synthetic-7-000-red-light" in page.read_text()
    assert main(["report", str(SAVED_V1), "--html", str(tmp_path / "v1.html")]) == 0


def test_a_newer_version_is_refused_with_one_sentence(tmp_path, capsys):
    newer = _write(tmp_path / "newer.json", {"schema_version": SCHEMA_VERSION + 1, **_saved()})
    with pytest.raises(ResultError) as error:
        load_result(newer)
    assert str(error.value) == (
        f"{newer}: result schema version {SCHEMA_VERSION + 1} is newer than this "
        f"wosac-eval reads (versions 1 to {SCHEMA_VERSION}): upgrade wosac-eval to read it"
    )
    assert main(["compare", str(SAVED_V1), str(newer)]) == 2
    assert "newer than this wosac-eval reads" in capsys.readouterr().err


@pytest.mark.parametrize("bad", ["2", 0, True, 1.0, None])
def test_a_version_that_is_no_whole_number_is_refused(bad):
    with pytest.raises(ResultError, match=r"'schema_version' is .*, expected a whole number >= 1"):
        parse_result({"schema_version": bad, **_saved()})


def test_an_earlier_document_stays_readable_when_the_registry_gains_a_field(monkeypatch):
    # A field the registry gains later (a new metric): the version 1 document lacks it and is read without
    # it; a document whose rows all carry it has it read.
    monkeypatch.setattr(result_reader, "SCENARIO_FIELDS", {**SCENARIO_FIELDS, "toy_likelihood": True})
    assert "toy_likelihood" not in load_result(SAVED_V1).values
    document = _saved()
    for k, row in enumerate(document["scenarios"]):
        row["toy_likelihood"] = 0.25 * (k + 1)
    read = parse_result(copy.deepcopy(document))
    assert np.array_equal(read.values["toy_likelihood"], [0.25, 0.5])
    # The fields of the document's own version are still required.
    del document["scenarios"][1]["metametric"]
    with pytest.raises(ResultError, match="has no field 'metametric'"):
        parse_result(document)


def test_the_newest_version_lists_every_field_the_registry_writes():
    assert SCHEMA_VERSION == max(VERSION_FIELDS)
    assert set(VERSION_FIELDS[SCHEMA_VERSION]) <= set(SCENARIO_FIELDS)
