"""The one walk over a submission and the handle the stages share (`parse.submission_source`)."""

from __future__ import annotations

import functools
import shutil

import pytest

from wosac_eval.parse.errors import ArchiveError, SizeLimitError
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.parse.shards import split_shard
from wosac_eval.parse.shard_walk import NotAShardError, iter_shard_refs, iter_submission_shards
from wosac_eval.parse.submission_source import SubmissionSource, read_locator
from wosac_eval.results.scene_plot import scene_pictures
from wosac_eval.scoring.submission import score_submission
from wosac_eval.sim import baselines, scenes
from wosac_eval.sim.scene_recipes import SCENE_KINDS
from wosac_eval.validate import validate_submission


@functools.lru_cache(maxsize=None)
def _scene(kind: str):
    return scenes.generate_scene(0, SCENE_KINDS.index(kind))


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """(scenario shard paths, a two-shard .tar.gz submission) of three synthetic scenes."""
    root = tmp_path_factory.mktemp("source")
    paths = scenes.write_scenario_shards(
        [_scene("intersection"), _scene("occlusion"), _scene("cyclists")], root / "scenarios", 2
    )
    archive = baselines.make_submission(paths, "constant_velocity", root / "cv.tar.gz", num_shards=2)
    return paths, archive


def _expected_rollouts(archive) -> dict[str, bytes]:
    return {sid: data for name, raw in iter_submission_shards(archive) for sid, data in split_shard(name, raw)}


def test_spooled_archive_is_decompressed_once(demo, tmp_path):
    """After validation walked it, scoring's and the pictures' reads come from the spool: the archive
    itself may be gone."""
    paths, archive = demo
    expected = _expected_rollouts(archive)
    moved = shutil.copy(archive, tmp_path / "upload.tar.gz")
    with SubmissionSource(moved, spool_dir=tmp_path) as source:
        report = validate_submission(paths, source)
        assert report.ok, report.format_text()
        (tmp_path / "upload.tar.gz").unlink()  # no stage after validation may read it again
        got = {sid: read_locator(locator) for sid, locator in source.rollouts_locators()}
        assert got == expected
        some = sorted(expected)[:2]
        assert {sid: r.SerializeToString() for sid, r in source.rollouts(some).items()} == {
            sid: expected[sid] for sid in some
        }
        spool_files = [p for p in tmp_path.rglob("*") if p.is_file()]
        assert spool_files, "the members were spooled"
    assert not any(p.is_file() for p in tmp_path.rglob("*")), "close() removes the spool"


def test_archive_without_spool_is_streamed_again_under_its_limits(demo, tmp_path):
    paths, archive = demo
    moved = shutil.copy(archive, tmp_path / "upload.tar.gz")
    source = SubmissionSource(moved)
    assert validate_submission(paths, source).ok
    assert {sid: read_locator(loc) for sid, loc in source.rollouts_locators()} == _expected_rollouts(archive)
    (tmp_path / "upload.tar.gz").unlink()
    with pytest.raises(FileNotFoundError):
        list(source.rollouts_locators())


def test_scoring_through_a_spooled_source_equals_scoring_the_path(demo, tmp_path):
    paths, archive = demo
    by_path = score_submission(paths, archive, analysis=False)
    index = ScenarioIndex(paths)
    with SubmissionSource(archive, spool_dir=tmp_path) as source:
        by_source = score_submission(index, source, analysis=False)
        pictures = scene_pictures(index, source, [s["scenario_id"] for s in by_source["scenarios"]][:1])
    for document in (by_path, by_source):
        document["validation"].pop("elapsed_s", None)
        document.pop("elapsed_s", None)
    assert by_source["scenarios"] == by_path["scenarios"]
    assert by_source["buckets"] == by_path["buckets"]
    assert len(pictures) == 1 and pictures[0][1].startswith(b"\x89PNG")


def _folder(tmp_path, demo):
    _, archive = demo
    folder = tmp_path / "shards"
    folder.mkdir()
    for name, raw in iter_submission_shards(archive):
        (folder / name.replace("/", "_")).write_bytes(raw)
    (folder / "notes.json").write_text("{}")
    (folder / "README.md").write_text("documentation is skipped")
    return folder


def test_folder_walk_policy_raise_or_report_and_go_on(tmp_path, demo):
    folder = _folder(tmp_path, demo)
    with pytest.raises(NotAShardError, match="'notes.json' is neither a submission shard"):
        list(iter_shard_refs(folder))
    problems: list[Exception] = []
    shards = list(iter_shard_refs(folder, problems=problems.append))
    assert len(shards) == 2 and all(s.path is not None and s.data is None for s in shards)
    assert [type(p) for p in problems] == [NotAShardError] and problems[0].shard == "notes.json"


def test_folder_size_limits_under_both_policies(tmp_path, demo):
    folder = _folder(tmp_path, demo)
    (folder / "notes.json").unlink()
    sizes = sorted(p.stat().st_size for p in folder.glob("*binproto*"))
    small = InputLimits(max_member_bytes=sizes[0])  # the larger shard is over it (or both equal: none)
    problems: list[Exception] = []
    kept = list(iter_shard_refs(folder, limits=small, problems=problems.append))
    over = [p for p in problems if isinstance(p, SizeLimitError)]
    assert len(kept) + len(over) == 2 and all("per-member limit" in str(p) for p in over)
    total = InputLimits(max_total_bytes=sizes[0])
    with pytest.raises(SizeLimitError, match="the remaining shards are not read"):
        list(iter_shard_refs(folder, limits=total))


def test_empty_folder_and_missing_path(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ArchiveError, match="folder holds no submission shard"):
        list(iter_shard_refs(tmp_path / "empty"))
    problems: list[Exception] = []
    assert list(iter_shard_refs(tmp_path / "empty", problems=problems.append)) == []
    assert len(problems) == 1 and "holds no submission shard" in str(problems[0])
    with pytest.raises(FileNotFoundError):
        iter_shard_refs(tmp_path / "absent.tar.gz", problems=problems.append)
