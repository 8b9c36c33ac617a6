"""Partial scoring means "score the valid scenarios and list the others": never past metadata errors,
always past an archive whose end is cut off (the shards before the cut are scored)."""

from __future__ import annotations

import io
import json
import tarfile

import pytest

from wosac_eval.arrays.submission_writer import SubmissionMetadata
from wosac_eval.parse.shard_walk import iter_submission_shards
from wosac_eval.sim import baselines, scenes

from support.runs import run_cli


def _scenarios(tmp_path):
    return scenes.write_scenario_shards(scenes.generate_scenes(3, seed=0), tmp_path / "scenarios", 1)


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_partial_never_goes_past_metadata_errors(tmp_path):
    paths = _scenarios(tmp_path)
    anonymous = SubmissionMetadata(unique_method_name="cv", account_name="")
    submission = baselines.make_submission(paths, "constant_velocity", tmp_path / "cv.tar.gz", metadata=anonymous)
    args = [
        "score",
        "--scenarios",
        *map(str, paths),
        "--submission",
        str(submission),
        "--strict-metadata",
        "-o",
        str(tmp_path / "r.json"),
    ]
    proc = run_cli(*args, "--partial")
    assert proc.returncode == 1, proc.stderr
    assert "metadata" in proc.stderr and "partial scoring skips invalid scenarios, never the metadata" in proc.stderr
    assert not (tmp_path / "r.json").exists()
    assert run_cli(*args[:-3], "-o", str(tmp_path / "r.json"), "--partial").returncode == 0  # warnings only


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_partial_scores_the_shards_before_a_cut_off_end(tmp_path):
    paths = _scenarios(tmp_path)
    whole = baselines.make_submission(paths, "constant_velocity", tmp_path / "cv.tar.gz", num_shards=3)
    shards = list(iter_submission_shards(whole))
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:  # uncompressed: the cut lands in the last member
        for name, data in shards:
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    raw = buffer.getvalue()
    cut = tmp_path / "cut.tar"
    cut.write_bytes(raw[: len(raw) - 512 * 4 - len(shards[-1][1]) // 2])
    args = ["score", "--scenarios", *map(str, paths), "--submission", str(cut), "-o", str(tmp_path / "r.json")]
    refused = run_cli(*args)
    assert refused.returncode == 1 and "--partial" in refused.stderr
    proc = run_cli(*args, "--partial")
    assert proc.returncode == 0, proc.stderr
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["num_scenarios"] == 2 and len(result["skipped"]) == 1
