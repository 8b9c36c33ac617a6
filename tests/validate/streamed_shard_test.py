"""A shard is checked one scenario at a time, with the whole parse's result (`validate.validator.check_shard`,
`parse.shard_stream`), and an archive is walked without holding a member whole (`SubmissionSource.shards`)."""

from __future__ import annotations

import functools
import tarfile
import tempfile
import tracemalloc

import numpy as np
import pytest

from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.shard_walk import ShardRef, iter_submission_shards
from wosac_eval.parse.submission_source import SubmissionSource, read_locator
from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.sim import baselines, scenes
from wosac_eval.sim.scene_recipes import SCENE_KINDS
from wosac_eval.validate import validate_submission
from wosac_eval.validate.shard_checks import check_shard, check_shard_whole

COPIES = 24  # scenarios of the large shard: ~1 MB each


@functools.cache
def _scene(kind: str):
    return scenes.generate_scene(0, SCENE_KINDS.index(kind))


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """(scenario shard paths, a one-shard .tar.gz submission, its shard's bytes)."""
    root = tmp_path_factory.mktemp("streamed")
    paths = scenes.write_scenario_shards([_scene("intersection"), _scene("cyclists")], root / "scenarios", 1)
    archive = baselines.make_submission(paths, "constant_velocity", root / "cv.tar.gz", num_shards=1)
    ((name, raw),) = list(iter_submission_shards(archive))
    return paths, archive, name, raw


@pytest.fixture(scope="module")
def large(demo, tmp_path_factory):
    """(a .tar.gz of one shard holding COPIES re-identified scenarios, that shard's bytes, its largest
    scenario's size)."""
    _, _, name, raw = demo
    submission = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw)
    first = submission.scenario_rollouts[0]
    for i in range(COPIES - len(submission.scenario_rollouts)):
        copy = submission.scenario_rollouts.add()
        copy.CopyFrom(first)
        copy.scenario_id = f"copy-{i}"
    shard = submission.SerializeToString()
    root = tmp_path_factory.mktemp("large")
    (root / name).write_bytes(shard)
    with tarfile.open(root / "large.tar.gz", "w:gz", compresslevel=1) as tar:
        tar.add(root / name, arcname=name)
    largest = max(r.ByteSize() for r in submission.scenario_rollouts)
    return root / "large.tar.gz", shard, largest


def _summary(result) -> tuple:
    """Everything a ShardResult says, comparable."""
    rollouts = None if result.rollouts is None else result.rollouts.to_dict(include_skipped=True)
    return (
        result.name,
        result.size,
        result.parse_error,
        result.parse_code,
        result.metadata,
        [f.to_dict() for f in result.metadata_findings],
        result.empty_detail,
        result.entries,
        rollouts,
        result.spans if result.parse_error is None else None,
    )


def _both(raw: bytes, tmp_path, limits: InputLimits | None = None) -> tuple[tuple, tuple]:
    """check_shard of the bytes parsed whole, and streamed from a file (the same from the bytes)."""
    path = tmp_path / "shard.binproto"
    path.write_bytes(b"pad" + raw)  # at an offset, as a member of a spool
    agents = {"copy-0": np.array([1, 2, 3])}
    in_memory = ShardRef("s.binproto", len(raw), data=raw)
    whole = check_shard_whole(in_memory, agents, 20, limits=limits)
    streamed = check_shard(ShardRef("s.binproto", len(raw), path=str(path), offset=3), agents, 20, limits=limits)
    assert _summary(check_shard(in_memory, agents, 20, limits=limits)) == _summary(streamed)
    return _summary(whole), _summary(streamed)


def _variants(raw: bytes) -> dict[str, bytes]:
    """A valid shard and shards broken in each way the whole parse reports."""
    bad_id = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw)
    bad_id.scenario_rollouts[0].scenario_id = "\u00e9"
    bad_id_bytes = bad_id.SerializeToString().replace("\u00e9".encode(), b"\xff\xfe")
    bad_name = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw)
    bad_name.account_name = "\u00e9"
    return {
        "valid": raw,
        "empty": b"",
        "truncated": raw[:-7],
        "cut in the middle": raw[: len(raw) // 2],
        "a stray end of group": raw + b"\x1c",
        "a damaged scenario": raw[:40] + b"\xff" * 64 + raw[104:],
        "scenario id not UTF-8": bad_id_bytes,
        "metadata not UTF-8": bad_name.SerializeToString().replace("\u00e9".encode(), b"\xff\xfe"),
        "an unknown field": raw + b"\xf8\x07\x01",
        "not a shard": b'{"json": true}',
    }


VARIANTS = (
    "valid",
    "empty",
    "truncated",
    "cut in the middle",
    "a stray end of group",
    "a damaged scenario",
    "scenario id not UTF-8",
    "metadata not UTF-8",
    "an unknown field",
    "not a shard",
)


@pytest.mark.parametrize("variant", VARIANTS)
def test_a_shard_read_from_its_file_is_judged_as_the_whole_parse_judges_it(demo, large, tmp_path, variant):
    _, _, _, raw = demo
    whole, streamed = _both(_variants(raw)[variant], tmp_path)
    assert streamed == whole


def test_message_limits_are_refused_at_the_same_place(large, tmp_path):
    _, shard, _ = large
    for limits in (
        InputLimits(message_allowance=100, message_bytes=1 << 30),
        InputLimits(max_scenarios=3),
        InputLimits(max_objects=2),
        InputLimits(max_joint_scenes=5),
    ):
        whole, streamed = _both(shard, tmp_path, limits)
        assert whole[2] and whole[3] == "container.size_limit", whole[2]
        assert streamed == whole


def test_a_large_shard_is_checked_one_scenario_at_a_time(large, tmp_path):
    """The Python memory of checking a shard from its file follows its largest scenario, not its size."""
    _, shard, largest = large
    path = tmp_path / "large.binproto"
    path.write_bytes(shard)
    ref = ShardRef(path.name, len(shard), path=str(path))
    tracemalloc.start()
    try:
        result = check_shard(ref, {}, 20)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert result.parse_error is None and len(result.entries) == COPIES
    assert len(shard) > 20 * largest
    assert peak < 4 * largest, f"peak {peak} bytes for scenarios of at most {largest} bytes"


def test_an_archive_is_walked_without_holding_a_member(large, tmp_path, monkeypatch):
    """Members go to scratch files a piece at a time, removed once checked and by close()."""
    archive, shard, _ = large
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    source = SubmissionSource(archive)
    tracemalloc.start()
    try:
        refs = []
        for ref in source.shards():
            refs.append(ref)
            _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    ((ref,),) = [refs]
    assert ref.data is None and ref.read() == shard
    assert peak < len(shard) // 2, f"peak {peak} bytes walking a {len(shard)}-byte member"
    source.release(ref.name)
    assert not [p for p in tmp_path.rglob("*") if p.is_file()], "release() removes the member's scratch file"
    source.close()
    assert not list(tmp_path.iterdir()), "close() removes the scratch folder"


def test_validation_of_an_archive_leaves_no_scratch_file(demo, tmp_path, monkeypatch):
    paths, archive, _, _ = demo
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "scratch"))
    (tmp_path / "scratch").mkdir()
    assert validate_submission(paths, archive).ok
    assert not list((tmp_path / "scratch").iterdir())
    with SubmissionSource(archive) as source:
        assert validate_submission(paths, source).ok
        assert not [p for p in (tmp_path / "scratch").rglob("*") if p.is_file()]


def test_a_resumed_read_of_an_archive_reads_only_what_is_left(demo):
    """`rollouts_locators(wanted)`: what is declined comes as None, unread; the rest as its bytes."""
    paths, archive, _, raw = demo
    expected = {
        r.scenario_id: r.SerializeToString()
        for r in sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw).scenario_rollouts
    }
    last = list(expected)[-1]
    with SubmissionSource(archive) as source:
        assert validate_submission(paths, source).ok
        got = list(source.rollouts_locators(lambda sid: sid == last))
        assert [sid for sid, _ in got] == list(expected)
        assert {sid: None if loc is None else read_locator(loc) for sid, loc in got} == {
            sid: data if sid == last else None for sid, data in expected.items()
        }
        assert {sid: read_locator(loc) for sid, loc in source.rollouts_locators()} == expected


def test_members_for_other_hosts_carry_their_bytes(large):
    """Workers on other nodes cannot read this host's scratch files: the walk then gives the bytes."""
    archive, shard, _ = large
    with SubmissionSource(archive) as source:
        (ref,) = list(source.shards(members_in_memory=True))
        assert ref.data == shard
        assert _summary(check_shard(ref, {}, 20)) == _summary(check_shard_whole(ref, {}, 20))
