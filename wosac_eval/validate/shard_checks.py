"""One shard checked on its own: its metadata and every scenario's rollouts, the rules that need nothing
from the other shards (so that shards can be checked in worker processes).

A shard is read from its file one scenario at a time (`parse.shard_stream`: archive
members are copied to a file a piece at a time by the walk), so a process holds one
scenario's bytes and message, whatever the shard's size. Only a shard that is not
well-formed at its top level, or that does not parse, is judged whole (read into
memory), so that its messages are those of a whole parse.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from google.protobuf.message import DecodeError

from wosac_eval import challenges
from wosac_eval.parse.decode import decode_message
from wosac_eval.parse.errors import ParseError, SizeLimitError
from wosac_eval.parse.limits import InputLimits, ShardCensus
from wosac_eval.parse.shard_stream import IrregularShard, iter_top_level_fields
from wosac_eval.parse.shard_walk import ShardRef
from wosac_eval.parse.shards import parse_submission_shard, string_fields_are_text
from wosac_eval.parse.wire import field_spans
from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.validate import metadata_rules, rules
from wosac_eval.validate.findings import Finding, ValidationReport


def validate_scenario_rollouts(
    rollouts_msg: sim_agents_submission_pb2.ScenarioRollouts,
    sim_agent_ids: np.ndarray | None,
    shard: str | None,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    wire_bytes: bytes | memoryview | None = None,
) -> list[Finding]:
    """The per-scenario rules (32 joint scenes, sim agents, 80 or 91 finite values per field, boxes and
    types for scenario gen) on one ScenarioRollouts.

    sim_agent_ids: ids of the scenario's objects valid at step 10, shape
    `(num_objects,)`, or None for a scenario outside the scenario set.
    wire_bytes: the bytes the message was parsed from (`rules.check_scenario_rollouts`).
    """
    return rules.check_scenario_rollouts(
        rollouts_msg, sim_agent_ids, shard=shard, challenge=challenge, wire_bytes=wire_bytes
    )


@dataclass
class ShardResult:
    """What checking one shard found, independent of the other shards (so shards can be checked in workers).

    rollouts: a report holding only the per-scenario rollout findings of this shard.
    entries: (index in scenario_rollouts, scenario_id or None) of every ScenarioRollouts, in order.
    spans: (start, end) of each ScenarioRollouts' bytes in the shard, in order (for the scorer,
      which then reads only those bytes).
    past_limit: set when the shard came after the submission's max_scenarios: not read further.
    """

    name: str
    size: int
    parse_error: str | None = None
    parse_code: str = "shard.unparseable"
    metadata: dict[str, Any] | None = None
    metadata_findings: list[Finding] = field(default_factory=list)
    empty_detail: str | None = None
    entries: list[tuple[int, str | None]] = field(default_factory=list)
    rollouts: ValidationReport | None = None
    spans: list[tuple[int, int]] = field(default_factory=list)
    past_limit: bool = False

    @property
    def readable(self) -> bool:
        """Whether the scoring pass may read this shard's entries."""
        return self.parse_error is None and not self.past_limit


def _check_shard_streamed(
    shard: ShardRef, agents: dict[str, np.ndarray], max_listed: int, challenge: Any, limits: InputLimits | None
) -> ShardResult | None:
    """`check_shard` of a shard in a file, read one top-level field at a time; None when the shard must be
    judged whole (its top level is not well-formed, a part does not parse, a string is not UTF-8).

    Each scenario_rollouts is parsed as a shard holding it alone (its field's own bytes), the metadata as
    the shard's other fields together: what a whole parse does, field by field, so that the result is the
    whole parse's. The messages are counted (`ShardCensus`) in the order `check_message_counts` counts them.
    """
    name = shard.name
    result = ShardResult(name, shard.size)
    census = ShardCensus(name, shard.size, limits)
    report = ValidationReport(name, max_listed=max_listed)
    metadata_fields: list[bytes] = []
    Submission = sim_agents_submission_pb2.SimAgentsChallengeSubmission
    with open(str(shard.path), "rb") if shard.data is None else io.BytesIO(shard.data) as f:
        f.seek(shard.offset if shard.data is None else 0)
        offset = 0  # of the field in the shard
        try:
            for number, wire_type, field_bytes, start, end in iter_top_level_fields(f, shard.size):
                try:
                    census.top_level_field(number, wire_type, field_bytes, start, end)
                except SizeLimitError as error:  # the whole shard's census stops here too
                    return ShardResult(name, shard.size, parse_error=str(error), parse_code="container.size_limit")
                if number != 1 or wire_type != 2:
                    metadata_fields.append(field_bytes)
                    offset += end
                    continue
                try:
                    (rollouts,) = decode_message(Submission, field_bytes).scenario_rollouts
                except DecodeError:
                    return None
                if not isinstance(rollouts.scenario_id, str):
                    return None
                scenario_id = rollouts.scenario_id or None  # unset or empty
                result.entries.append((len(result.entries), scenario_id))
                result.spans.append((offset + start, offset + end))
                if scenario_id is not None:
                    value = memoryview(field_bytes)[start:end]  # the ScenarioRollouts' own bytes
                    report.extend(validate_scenario_rollouts(rollouts, agents.get(scenario_id), name, challenge, value))
                offset += end
        except IrregularShard:
            return None
    try:
        metadata = decode_message(Submission, b"".join(metadata_fields))
    except DecodeError:
        return None
    if string_fields_are_text(metadata) is not None:
        return None
    result.metadata = metadata_rules.metadata_of(metadata)
    result.metadata_findings = metadata_rules.check_metadata(metadata, name)
    if not result.entries:
        result.empty_detail = "holds no scenario_rollouts" + (" (the shard is 0 bytes)" if not shard.size else "")
    result.rollouts = report
    return result


def check_shard(
    shard: ShardRef,
    agents: dict[str, np.ndarray],
    max_listed: int,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    limits: InputLimits | None = None,
) -> ShardResult:
    """Parse one shard and apply the rules that need nothing from other shards: metadata and rollouts.

    It is read one scenario at a time (`_check_shard_streamed`: from its file, or the bytes it carries),
    unless it must be judged whole."""
    if shard.data is not None or shard.path is not None:
        streamed = _check_shard_streamed(shard, agents, max_listed, challenge, limits)
        if streamed is not None:
            return streamed
    return check_shard_whole(shard, agents, max_listed, challenge, limits)


def check_shard_whole(
    shard: ShardRef,
    agents: dict[str, np.ndarray],
    max_listed: int,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    limits: InputLimits | None = None,
) -> ShardResult:
    """`check_shard` with the shard parsed whole: the reference the streamed check equals, and the judge of
    a shard that is not well-formed (its messages are a whole parse's)."""
    name, data = shard.name, shard.read()
    result = ShardResult(name, len(data))
    try:
        submission = parse_submission_shard(name, data, limits)
    except ParseError as error:
        result.parse_error = str(error)
        if isinstance(error, SizeLimitError):
            result.parse_code = "container.size_limit"
        return result
    result.metadata = metadata_rules.metadata_of(submission)
    result.metadata_findings = metadata_rules.check_metadata(submission, name)
    if not submission.scenario_rollouts:
        result.empty_detail = "holds no scenario_rollouts" + (" (the shard is 0 bytes)" if not data else "")
    result.rollouts = ValidationReport(name, max_listed=max_listed)
    result.spans = field_spans(data, 1)  # scenario_rollouts is field 1: its elements, in order
    for index, rollouts in enumerate(submission.scenario_rollouts):
        scenario_id = rollouts.scenario_id or None  # unset or empty
        result.entries.append((index, scenario_id))
        if scenario_id is not None:
            result.rollouts.extend(validate_scenario_rollouts(rollouts, agents.get(scenario_id), name, challenge))
    return result
