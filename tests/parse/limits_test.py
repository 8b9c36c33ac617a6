"""The input limits of the library, without the service: the wire census of a real submission at its
exact sizes, floods of empty messages, garbage bytes, the compression-ratio budget and max_scenarios
across shards (validation names the shard; partial scoring reads none of it). Real demo submissions,
real protobuf bytes."""

from __future__ import annotations

import functools
import gzip
import random
import re

import pytest

from wosac_eval.parse.archive import check_container
from wosac_eval.parse.shard_walk import iter_submission_shards
from wosac_eval.parse.errors import SizeLimitError
from wosac_eval.parse.limits import InputLimits, _Census, check_message_counts
from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.scoring.submission import InvalidSubmissionError, score_submission
from wosac_eval.validate.validator import validate_submission


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """Two synthetic scenes and a constant-velocity submission of two shards (one scene each)."""
    from wosac_eval.sim import scenes
    from wosac_eval.sim.baselines import make_submission

    work = tmp_path_factory.mktemp("limits")
    shards = scenes.write_scenario_shards(scenes.generate_scenes(2, seed=0), work / "scenarios", num_shards=2)
    return shards, make_submission(shards, "constant_velocity", work / "demo.tar.gz", num_shards=2)


def first_shard(submission):
    name, data = next(iter(iter_submission_shards(submission)))
    return name, data, sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(data)


def test_the_census_passes_a_real_shard_at_its_exact_sizes_and_refuses_one_below(demo):
    name, data, parsed = first_shard(demo[1])
    rollouts = parsed.scenario_rollouts[0]
    scenes, objects = len(rollouts.joint_scenes), len(rollouts.joint_scenes[0].simulated_trajectories)
    assert scenes == 32 and objects > 1
    check_message_counts(name, data)  # the defaults
    check_message_counts(name, data, InputLimits(max_scenarios=1, max_joint_scenes=scenes, max_objects=objects))
    with pytest.raises(
        SizeLimitError,
        match=rf"shard {name}: scenario_rollouts\[0\] holds more than "
        rf"max_joint_scenes={scenes - 1} joint_scenes",
    ):
        check_message_counts(name, data, InputLimits(max_joint_scenes=scenes - 1))
    with pytest.raises(
        SizeLimitError,
        match=rf"scenario_rollouts\[0\]\.joint_scenes\[0\] holds more than "
        rf"max_objects={objects - 1} simulated_trajectories",
    ):
        check_message_counts(name, data, InputLimits(max_objects=objects - 1))
    with pytest.raises(SizeLimitError, match="more than max_scenarios=0 scenario_rollouts"):
        check_message_counts(name, data, InputLimits(max_scenarios=0))


def test_a_flood_of_empty_messages_is_refused_before_parsing():
    limits = InputLimits()
    allowed = limits.message_allowance
    check_message_counts("few.binproto", b"\x0a\x00" * allowed)  # within the fixed allowance
    flood = b"\x0a\x00" * 20_000  # 40 kB: 20,000 empty scenario_rollouts
    budget = allowed + len(flood) // limits.message_bytes
    with pytest.raises(
        SizeLimitError,
        match=f"shard flood.binproto: more than {budget} messages in {len(flood)} bytes at the top level",
    ):
        check_message_counts("flood.binproto", flood)
    # The same flood one level down, empty trajectories of one joint scene: max_objects stops it first,
    # and the message budget where max_objects is raised past it.
    scene = b"\x0a\x00" * 20_000
    joint = b"\x12" + _varint(len(scene)) + scene
    nested = b"\x0a" + _varint(len(joint)) + joint
    with pytest.raises(SizeLimitError, match=r"joint_scenes\[0\] holds more than max_objects=4096"):
        check_message_counts("nested.binproto", nested)
    with pytest.raises(SizeLimitError, match=r"messages in 40000 bytes at scenario_rollouts\[0\]\.joint_scenes\[0\]"):
        check_message_counts("nested.binproto", nested, InputLimits(max_objects=10**6))


def _varint(value: int) -> bytes:
    from wosac_eval.parse.wire import varint

    return varint(value)


def test_garbage_bytes_never_break_the_census(demo):
    """Malformed bytes end the walk (the parser reports them): the census only ever refuses by a limit."""
    _, data, _ = first_shard(demo[1])
    rng = random.Random(7)
    for _ in range(300):
        sample = bytearray(data[: rng.randrange(1, 4096)])
        for _ in range(rng.randrange(1, 16)):  # flip bytes of a real prefix
            sample[rng.randrange(len(sample))] = rng.randrange(256)
        for blob in (bytes(sample), rng.randbytes(rng.randrange(1, 512))):
            try:
                check_message_counts("garbage.binproto", blob, InputLimits(message_allowance=64))
            except SizeLimitError:
                pass


def test_the_compression_ratio_budget_applies_to_a_compressed_shard(tmp_path):
    shard = tmp_path / "zeros.binproto.gz"
    shard.write_bytes(gzip.compress(b"\x10\x01" * 200_000))  # 400 kB in about 1 kB
    compressed = shard.stat().st_size
    limits = InputLimits(max_compression_ratio=10, ratio_floor_bytes=4096)
    for read in (lambda: list(iter_submission_shards(shard, limits=limits)), lambda: check_container(shard, limits)):
        with pytest.raises(SizeLimitError, match=f"max_compression_ratio: 10 times the {compressed} compressed"):
            read()
    assert len(next(iter(iter_submission_shards(shard)))[1]) == 400_000  # the default budget allows it


def test_max_scenarios_names_the_shard_past_it_and_partial_scoring_reads_none_of_it(demo):
    scenarios, submission = demo
    limits = InputLimits(max_scenarios=1)
    report = validate_submission(scenarios, submission, limits=limits)
    past = report.groups["container.size_limit"].listed
    assert len(past) == 1 and past[0].shard.endswith("00001-of-00002"), report.format_text()
    assert "max_scenarios=1" in past[0].message and report.stats.scenarios_submitted == 1
    with pytest.raises(InvalidSubmissionError):
        score_submission(scenarios, submission, "2025", limits=limits)
    partial = score_submission(scenarios, submission, "2025", limits=limits, allow_partial=True)
    whole = score_submission(scenarios, submission, "2025")
    assert [s["scenario_id"] for s in partial["scenarios"]] == [whole["scenarios"][0]["scenario_id"]]
    # The same metrics (criticality is ranked within the scored set, so it is left out here).
    assert {**partial["scenarios"][0], "criticality": None} == {**whole["scenarios"][0], "criticality": None}
    assert [s["scenario_id"] for s in partial["skipped"]] == [whole["scenarios"][1]["scenario_id"]]


def plain_census(shard: str, data: bytes, limits: InputLimits) -> str | None:
    """The census by its definition, the Python walk of `parse.limits` (`_Census.fields`, which walks the
    top level) down all three levels: the first refusal's message, or None. Every field of a walked level is
    one message; a malformed field ends its level's walk."""
    census = _Census(shard, len(data), limits)
    fields = functools.partial(census.fields, data)
    try:
        scenarios = 0
        for number, start, end in fields(0, len(data), "the top level"):
            if number != 1:
                continue
            scenarios += 1
            if scenarios > limits.max_scenarios:
                raise SizeLimitError(
                    f"shard {shard}: more than max_scenarios={limits.max_scenarios} scenario_rollouts; "
                    "refused before parsing"
                )
            where = f"scenario_rollouts[{scenarios - 1}]"
            joint_scenes = 0
            for number, j_start, j_end in fields(start, end, where):
                if number != 2:
                    continue
                joint_scenes += 1
                if joint_scenes > limits.max_joint_scenes:
                    raise SizeLimitError(
                        f"shard {shard}: {where} holds more than max_joint_scenes={limits.max_joint_scenes} "
                        "joint_scenes (the challenge asks for 32); refused before parsing"
                    )
                scene_where = f"{where}.joint_scenes[{joint_scenes - 1}]"
                objects = 0
                for number, _, _ in fields(j_start, j_end, scene_where):
                    objects += number == 1
                    if objects > limits.max_objects:
                        raise SizeLimitError(
                            f"shard {shard}: {scene_where} holds more than max_objects={limits.max_objects} "
                            "simulated_trajectories; refused before parsing"
                        )
    except SizeLimitError as refused:
        return str(refused)
    return None


def _census_outcome(data: bytes, limits: InputLimits) -> str | None:
    try:
        check_message_counts("census.binproto", data, limits)
    except SizeLimitError as error:
        return str(error)
    return None


def test_the_compiled_census_counts_and_refuses_as_the_plain_walk(demo):
    """The same refusal (or none) with the same message as the walk of the definition, on a real shard at
    tight limits, floods, damaged prefixes, random bytes and varints of 10 bytes and more (keys past 2^64)."""
    _, data, parsed = first_shard(demo[1])
    objects = len(parsed.scenario_rollouts[0].joint_scenes[0].simulated_trajectories)
    rng = random.Random(11)
    tight = [
        InputLimits(),
        InputLimits(max_joint_scenes=31),
        InputLimits(max_objects=objects - 1),
        InputLimits(message_allowance=0, message_bytes=1000),
        InputLimits(message_allowance=40, message_bytes=10**9),
        InputLimits(message_allowance=64),
    ]
    overlong = [b"\x12" + b"\xff" * 9 + b"\x7f", b"\x92" + b"\x80" * 8 + b"\x02" + b"\x00", b"\x0a\xff" + b"\x80" * 9]
    blobs = [data, data[: len(data) // 2], b"\x0a\x00" * 20_000]
    for tail in overlong:
        scene = b"\x12" + _varint(len(tail)) + tail
        blobs += [b"\x0a" + _varint(len(tail)) + tail, b"\x0a" + _varint(len(scene)) + scene + data[:300]]
    rollouts = parsed.scenario_rollouts[0].SerializeToString()
    for _ in range(200):
        sample = bytearray(rollouts[: rng.randrange(1, 6000)])
        for _ in range(rng.randrange(1, 16)):
            sample[rng.randrange(len(sample))] = rng.randrange(256)
        # Damaged within a well-formed scenario_rollouts field (the walk enters it), and as a shard's start.
        blobs += [b"\x0a" + _varint(len(sample)) + bytes(sample), bytes(sample), rng.randbytes(rng.randrange(1, 512))]
    kinds = set()
    for blob in blobs:
        for limits in [*tight, InputLimits(message_allowance=rng.randrange(1, 1500), message_bytes=10**9)]:
            want = plain_census("census.binproto", blob, limits)
            assert _census_outcome(blob, limits) == want
            if want is not None:  # which limit, at which level
                kinds.add(re.sub(r"\d+", "N", want.split(" holds more than ")[-1].split(" bytes at ")[-1])[:28])
    assert kinds == {
        "the top level (one per N byt",
        "scenario_rollouts[N] (one pe",
        "scenario_rollouts[N].joint_s",
        "max_joint_scenes=N joint_sce",
        "max_objects=N simulated_traj",
    }  # every limit was reached, the message budget at every level
