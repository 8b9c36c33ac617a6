"""Property tests: any bytes either parse or raise ParseError, never anything else."""

from __future__ import annotations

import gzip
import io
import os
import tarfile
import warnings
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.shards import parse_submission_shard
from wosac_eval.parse.shard_walk import iter_submission_shards
from wosac_eval.parse.errors import ParseError
from wosac_eval.parse.scenarios import ScenarioSource, parse_scenario, scenario_id_of
from wosac_eval.parse.tfrecord import frame_record, iter_records
from wosac_eval.protos import sim_agents_submission_pb2

# WOSAC_FUZZ_EXAMPLES=5000 for a longer local hunt; the default keeps CI quick.
FUZZ = settings(
    max_examples=int(os.environ.get("WOSAC_FUZZ_EXAMPLES", "150")),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)


def valid_submission() -> bytes:
    """A small valid shard to mutate."""
    submission = sim_agents_submission_pb2.SimAgentsChallengeSubmission(account_name="a")
    scene = submission.scenario_rollouts.add(scenario_id="s").joint_scenes.add()
    scene.simulated_trajectories.add(object_id=3, center_x=[1.0, 2.0], heading=[0.5, 0.5])
    return submission.SerializeToString()


def valid_tar(compress: bool) -> bytes:
    """A small valid submission tarball to mutate."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz" if compress else "w") as tar:
        for name in ("a.binproto", "b.binproto"):
            data = valid_submission()
            info = tarfile.TarInfo(f"sub/{name}")
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return buffer.getvalue()


def mutated(seed: bytes) -> st.SearchStrategy[bytes]:
    """seed cut at a random point, or with one byte replaced, or with bytes appended."""
    cut = st.integers(0, len(seed)).map(lambda n: seed[:n])
    flip = st.tuples(st.integers(0, len(seed) - 1), st.integers(0, 255)).map(
        lambda p: seed[: p[0]] + bytes([p[1]]) + seed[p[0] + 1 :]
    )
    extend = st.binary(max_size=64).map(lambda tail: seed + tail)
    return st.one_of(cut, flip, extend)


SHARD_BYTES = st.one_of(st.binary(max_size=512), mutated(valid_submission()))
RECORD_FILE_BYTES = st.one_of(
    st.binary(max_size=256),
    mutated(frame_record(b"hello") + frame_record(valid_submission())),
)
ARCHIVE_BYTES = st.one_of(
    st.binary(max_size=1024),
    mutated(valid_tar(compress=False)),
    mutated(valid_tar(compress=True)),
    mutated(gzip.compress(valid_submission())),
)


@FUZZ
@given(raw=SHARD_BYTES)
def test_shard_parser_raises_only_parse_errors(raw):
    try:
        parse_submission_shard("fuzz.binproto", raw)
    except ParseError as error:
        assert "fuzz.binproto" in str(error)


@FUZZ
@given(raw=SHARD_BYTES)
def test_scenario_parsers_raise_only_parse_errors(raw):
    source = ScenarioSource(Path("fuzz.tfrecord"), 0)
    for parse in (parse_scenario, scenario_id_of):
        try:
            parse(raw, source)
        except ParseError as error:
            assert "fuzz.tfrecord" in str(error)


@FUZZ
@pytest.mark.parametrize("name", ["fuzz.tfrecord", "fuzz.tfrecord.gz"])
@given(raw=RECORD_FILE_BYTES)
def test_tfrecord_reader_raises_only_parse_errors(tmp_path, name, raw):
    path = tmp_path / name
    path.write_bytes(gzip.compress(raw) if name.endswith(".gz") else raw)
    try:
        records = list(iter_records(path))
    except ParseError as error:
        assert name in str(error)
    else:
        assert all(isinstance(r.data, bytes) for r in records)


@FUZZ
@pytest.mark.parametrize("name", ["fuzz.binproto", "fuzz.tar", "fuzz.tar.gz"])
@given(raw=ARCHIVE_BYTES)
def test_archive_reader_raises_only_parse_errors(tmp_path, name, raw):
    path = tmp_path / name
    path.write_bytes(raw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # misnamed content is allowed to warn
        try:
            for shard_name, data in iter_submission_shards(path, limits=InputLimits(max_member_bytes=1 << 16)):
                try:
                    parse_submission_shard(shard_name, data)
                except ParseError:
                    pass
        except ParseError as error:
            assert name in str(error)
