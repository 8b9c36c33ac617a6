"""Property tests: malformed bytes in any container give a report (a clean finding), never a traceback."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wosac_eval.validate import ValidationReport, load_sim_agents, validate_submission
from support.submissions import golden_submission, scenario_path, tar_bytes, with_rollouts

SID = "637f20cafde22ff8"
# WOSAC_FUZZ_EXAMPLES=2000 for a deeper local run; the default keeps the suite fast.
FUZZ = settings(
    max_examples=int(os.environ.get("WOSAC_FUZZ_EXAMPLES", "60")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)


@pytest.fixture(scope="module")
def agents():
    return load_sim_agents([scenario_path(SID)])


@pytest.fixture(scope="module")
def small_shard() -> bytes:
    """A real shard, cut to 2 joint scenes of 3 objects so fuzzing is fast (invalid, but well-formed)."""
    template = golden_submission(f"{SID}__logreplay")
    rollouts = template.scenario_rollouts[0]
    del rollouts.joint_scenes[2:]
    for scene in rollouts.joint_scenes:
        del scene.simulated_trajectories[3:]
    return with_rollouts(template, [rollouts]).SerializeToString()


def run(agents, name: str, data: bytes) -> ValidationReport:
    """Validate data written under name; the report must render as text and JSON."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / name
        path.write_bytes(data)
        report = validate_submission([], path, sim_agents=agents)
    assert isinstance(report.format_text(), str)
    json.dumps(report.to_dict())
    return report


def mutate(data: bytes, edits) -> bytes:
    """Apply (position, operation, byte) edits: overwrite, insert, delete or truncate."""
    buffer = bytearray(data)
    for position, operation, value in edits:
        if not buffer:
            break
        i = position % len(buffer)
        if operation == "flip":
            buffer[i] ^= value or 1
        elif operation == "insert":
            buffer.insert(i, value)
        elif operation == "delete":
            del buffer[i]
        else:
            del buffer[i:]
    return bytes(buffer)


EDITS = st.lists(
    st.tuples(st.integers(0, 1 << 30), st.sampled_from(["flip", "insert", "delete", "truncate"]), st.integers(0, 255)),
    min_size=1,
    max_size=6,
)


@FUZZ
@given(data=st.binary(max_size=4096), name=st.sampled_from(["s.binproto", "s.tar.gz", "s.tar", "s.binproto.gz", "s"]))
def test_random_bytes_give_an_invalid_report(agents, data, name):
    report = run(agents, name, data)
    assert not report.ok  # nothing random is a complete submission of scenario SID
    assert report.error_count > 0


@FUZZ
@given(edits=EDITS)
def test_mutated_shard_gives_a_report(agents, small_shard, edits):
    report = run(agents, "s.binproto", mutate(small_shard, edits))
    assert not report.ok
    for finding in report.findings():
        assert finding.message and finding.code


@FUZZ
@given(edits=EDITS, gz=st.booleans())
def test_mutated_archive_gives_a_report(agents, small_shard, edits, gz):
    archive = tar_bytes({"a.binproto": small_shard, "b/c.binproto": small_shard}, gzip=gz)
    report = run(agents, "s.tar.gz" if gz else "s.tar", mutate(archive, edits))
    assert not report.ok


@FUZZ
@given(edits=EDITS)
def test_corrupt_scenario_set_is_a_clean_usage_error(edits):
    from wosac_eval.validate import ScenarioSetError

    original = scenario_path(SID).read_bytes()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "set.tfrecord"
        path.write_bytes(mutate(original, edits))
        try:
            agents = load_sim_agents([path])
        except ScenarioSetError as error:
            assert "set.tfrecord" in str(error)  # names the file at fault
        else:
            assert all(a.dtype.kind == "i" for a in agents.values())


@settings(
    FUZZ,
    max_examples=min(FUZZ.max_examples, 30),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(data=st.binary(max_size=2048), name=st.sampled_from(["s.binproto", "s.tar.gz", "s.tar"]))
def test_cli_on_random_bytes_exits_1_with_a_report(capsys, data, name):
    from wosac_eval.fronts.cli import main

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / name
        path.write_bytes(data)
        code = main(["validate", "--scenarios", str(scenario_path(SID)), "--submission", str(path), "--json"])
    out = capsys.readouterr()
    assert code == 1, out.err
    report = json.loads(out.out)
    assert report["valid"] is False and report["groups"]
