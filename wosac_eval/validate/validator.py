"""Validate a whole submission against a scenario set, streaming shard by shard.

Memory stays bounded: from the scenario set only the sim agent ids of each
scenario are kept (a few hundred bytes per scenario); a shard is read from its
file one scenario at a time (`parse.shard_stream`: archive members are copied to
a file a piece at a time by the walk), so a process holds one scenario's bytes
and message, whatever the shard's size; the report keeps counts and the first
findings of each kind. Only a shard that is not well-formed at its top level, or
that does not parse, is judged whole (read into memory), so that its messages are
those of a whole parse.
"""

from __future__ import annotations

import collections
import dataclasses
import io
import os
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from google.protobuf.message import DecodeError

from wosac_eval import challenges
from wosac_eval.arrays.scenario import record_sim_agent_ids
from wosac_eval.parse.archive import ArchiveNameWarning, UncompressedTarWarning
from wosac_eval.parse.decode import decode_message
from wosac_eval.parse.errors import ParseError, SizeLimitError, UnsafeArchiveMemberError
from wosac_eval.parse.limits import InputLimits, ShardCensus
from wosac_eval.parse.scenarios import ScenarioIndex, ScenarioSource, expand_scenario_paths, scenario_id_of
from wosac_eval.parse.shard_stream import IrregularShard, iter_top_level_fields
from wosac_eval.parse.shards import parse_submission_shard, string_fields_are_text
from wosac_eval.parse.submission_source import NotAShardError, ShardRef, SubmissionSource
from wosac_eval.parse.tfrecord import iter_records, read_record_at
from wosac_eval.parse.wire import field_spans
from wosac_eval.parse.wire_walks import compile_walks
from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.runtime.executors import LocalExecutor
from wosac_eval.validate import rules
from wosac_eval.validate.findings import WARNING, Finding, ValidationReport, make_finding

PathLike = str | os.PathLike


METADATA_CHECKS = ("error", "warn")  # how metadata findings count: as the challenge server, or as warnings


class ScenarioSetError(ValueError):
    """The scenario set itself cannot be read: the submission cannot be judged (a usage error)."""


def _record_sim_agents(record: bytes, source: ScenarioSource) -> np.ndarray:
    """Sorted sim agent ids of a serialized scenario, read from its tracks alone: a whole parse of each
    scenario cost the validation about a third of its time (a real WOMD scene: 2-6 ms)."""
    return np.unique(record_sim_agent_ids(record, source))


def _sim_agents_of(_shared, item: tuple[str, list[int]]) -> list[np.ndarray]:
    """Sorted sim agent ids of the scenarios at these offsets of one scenario file (a worker task)."""
    path, offsets = item
    return [_record_sim_agents(read_record_at(path, offset), ScenarioSource(Path(path), offset)) for offset in offsets]


def load_sim_agents(
    scenarios: ScenarioIndex | PathLike | Iterable[PathLike],
    progress: Callable[[int], Any] | None = None,
    executor=None,
) -> dict[str, np.ndarray]:
    """scenario_id -> sorted sim agent ids, shape (num_sim_agents,), in scenario-set order.

    Streams the scenarios (or, from a ScenarioIndex, loads them by batches in
    the executor's workers) and keeps only the ids of objects valid at step
    10. Raises ScenarioSetError when a scenario file is missing or corrupt, or
    a scenario_id occurs twice. progress: called with the number of scenarios
    read after each batch.
    """
    agents: dict[str, np.ndarray] = {}
    try:
        if isinstance(scenarios, ScenarioIndex):
            batches = _index_batches(scenarios)
            for (ids, _), found in zip(
                batches,
                (executor or LocalExecutor()).imap(_sim_agents_of, ((path, offsets) for _, (path, offsets) in batches)),
            ):
                agents.update(zip(ids, found))
                if progress is not None:
                    progress(len(ids))
        else:
            first_source: dict[str, Any] = {}
            for path in expand_scenario_paths(scenarios):
                for record in iter_records(path):
                    source = ScenarioSource(path, record.offset)
                    sid = scenario_id_of(record.data, source)
                    if sid in agents:
                        raise ScenarioSetError(f"scenario {sid!r} occurs twice: in {first_source[sid]} and in {source}")
                    first_source[sid] = source
                    agents[sid] = _record_sim_agents(record.data, source)
                    if progress is not None:
                        progress(1)
    except (ParseError, OSError) as error:
        raise ScenarioSetError(f"cannot read the scenario set: {error}") from error
    return agents


_SCENARIOS_PER_BATCH = 64


def _index_batches(index: ScenarioIndex) -> list[tuple[list[str], tuple[str, list[int]]]]:
    """The index's scenarios in batches of one file: (ids, (path, offsets)), in index order."""
    batches: list = []
    for sid in index:
        source = index.source(sid)
        path = str(source.path)
        if not batches or batches[-1][1][0] != path or len(batches[-1][0]) == _SCENARIOS_PER_BATCH:
            batches.append(([], (path, [])))
        batches[-1][0].append(sid)
        batches[-1][1][1].append(source.offset)
    return batches


def _container_finding(problem: Exception) -> Finding:
    """A finding for a problem of the submission's container, as the walk reports it (its message names
    the file and member)."""
    if isinstance(problem, ArchiveNameWarning):
        return Finding("container.misnamed", str(problem), severity=WARNING)
    if isinstance(problem, UncompressedTarWarning):
        return Finding("container.not_gzipped", str(problem), severity=WARNING)
    if isinstance(problem, NotAShardError):
        return Finding("container.not_a_shard", str(problem), shard=problem.shard)
    if isinstance(problem, UnsafeArchiveMemberError):
        return Finding("container.unsafe_member", str(problem))
    if isinstance(problem, SizeLimitError):
        return Finding("container.size_limit", str(problem), shard=problem.shard)
    return Finding("container.unreadable", str(problem))


def validate_scenario_rollouts(
    rollouts_msg: Any,
    sim_agent_ids: Any,
    shard: str | None,
    challenge: Any = challenges.Challenge.SIM_AGENTS,
    wire_bytes: bytes | memoryview | None = None,
) -> list[Finding]:
    """The per-scenario rules (32 joint scenes, sim agents, 80 or 91 finite values per field, boxes and
    types for scenario gen) on one ScenarioRollouts.

    sim_agent_ids: ids of the scenario's objects valid at step 10, shape
    (num_sim_agents,), or None for a scenario outside the scenario set.
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
    result.metadata = rules.metadata_of(metadata)
    result.metadata_findings = rules.check_metadata(metadata, name)
    if not result.entries:
        result.empty_detail = "holds no scenario_rollouts" + (" (the shard is 0 bytes)" if not shard.size else "")
    result.rollouts = report
    return result


def check_shard(
    shard: ShardRef,
    agents: dict[str, np.ndarray],
    max_listed: int,
    challenge: Any = challenges.Challenge.SIM_AGENTS,
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
    challenge: Any = challenges.Challenge.SIM_AGENTS,
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
    result.metadata = rules.metadata_of(submission)
    result.metadata_findings = rules.check_metadata(submission, name)
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


def _check_shard_task(shared: tuple, shard: ShardRef) -> ShardResult:
    """`check_shard` in a worker; `shared` is (agents, max_listed, challenge name, limits)."""
    agents, max_listed, challenge, limits = shared
    return check_shard(shard, agents, max_listed, challenge, limits)


class _Validation:
    """Merges shard results, in shard order, into the report; applies the cross-shard rules.

    Cross-shard rules (metadata consistency, duplicate and unknown scenarios)
    need the order of the shards, so they run here, in the main process;
    merging in shard order makes the report identical for any worker count.
    """

    def __init__(
        self,
        agents: dict[str, np.ndarray],
        report: ValidationReport,
        progress: Callable[[int], Any] | None,
        metadata_checks: str = "error",
        max_scenarios: int = InputLimits.max_scenarios,
    ):
        self.agents = agents
        self.max_scenarios = max_scenarios
        self.metadata_checks = metadata_checks
        self.report = report
        self.progress = progress
        self.first_seen: dict[str, tuple[str, int]] = {}
        self.reference_metadata: dict[str, Any] | None = None
        self.reference_shard = ""
        self.checked_metadata: set[tuple] = set()

    def merge(self, result: ShardResult) -> None:
        report, name = self.report, result.name
        report.stats.shards += 1
        report.stats.bytes_read += result.size
        if result.parse_error is not None:
            report.add(Finding(result.parse_code, result.parse_error, shard=name))
            return
        if report.stats.scenarios_submitted + len(result.entries) > self.max_scenarios:
            # Bounded memory: the scenarios past the limit are not recorded (nor scored).
            report.add(
                Finding(
                    "container.size_limit",
                    f"shard {name}: the submission holds more than "
                    f"max_scenarios={self.max_scenarios} scenario_rollouts; this shard is not read",
                    shard=name,
                )
            )
            result.past_limit = True
            return
        # A shard read without a parse error has its metadata and rollout report.
        assert result.metadata is not None and result.rollouts is not None
        self.metadata(name, result.metadata, result.metadata_findings)
        if result.empty_detail is not None:
            report.add(make_finding("shard.empty", result.empty_detail, shard=name))
        for index, scenario_id in result.entries:
            self.coverage(name, index, scenario_id)
        report.merge(result.rollouts)
        report.stats.scenarios_submitted += len(result.entries)
        if self.progress is not None and result.entries:
            self.progress(len(result.entries))

    def metadata(self, name: str, metadata: dict[str, Any], findings: list[Finding]) -> None:
        key = tuple(metadata.values())
        # Shards written by one tool share their metadata: report each distinct
        # set's faults once, so a fault common to 150 shards is one finding, not 150.
        if key not in self.checked_metadata:
            self.checked_metadata.add(key)
            self.report.extend(self.graded(findings))
        if self.reference_metadata is None:
            self.reference_metadata, self.reference_shard = metadata, name
        else:
            self.report.extend(
                self.graded(
                    rules.check_metadata_consistency(self.reference_metadata, self.reference_shard, metadata, name)
                )
            )

    def graded(self, findings: list[Finding]) -> list[Finding]:
        """Metadata findings at the severity asked for: local scoring needs no account or flags."""
        if self.metadata_checks == "error":
            return findings
        return [dataclasses.replace(f, severity=WARNING) for f in findings]

    def coverage(self, name: str, index: int, scenario_id: str | None) -> None:
        report = self.report
        if scenario_id is None:
            report.add(rules.missing_scenario_id(name, index))
            return
        first = self.first_seen.get(scenario_id)
        if first is not None:
            report.add(rules.duplicate_scenario(scenario_id, name, index, first))
        else:
            self.first_seen[scenario_id] = (name, index)
        if scenario_id not in self.agents:
            report.add(rules.unknown_scenario(scenario_id, name, index))


def _shard_results(
    shards: Iterable[ShardRef],
    agents: dict[str, np.ndarray],
    max_listed: int,
    executor,
    challenge: challenges.Challenge,
    limits: InputLimits,
) -> Iterator[ShardResult]:
    """Check every shard with the executor (this process, worker processes or Ray); results in shard order.

    A shard per worker is in flight, and none waiting (an official shard is 300-400 MB decompressed):
    memory stays bounded by a few shards (shards of folders are byte ranges: the workers read them).
    """
    return executor.imap(_check_shard_task, shards, (agents, max_listed, challenge.value, limits), ahead=0)


def validate_submission(
    scenarios: ScenarioIndex | PathLike | Iterable[PathLike],
    submission: PathLike | SubmissionSource,
    *,
    max_listed: int = 20,
    limits: InputLimits | None = None,
    progress: Callable[[int], Any] | None = None,
    sim_agents: dict[str, np.ndarray] | None = None,
    workers: int = 1,
    challenge: Any = challenges.Challenge.SIM_AGENTS,
    executor=None,
    metadata_checks: str = "error",
) -> ValidationReport:
    """Check a submission (.tar.gz, .tar, folder or .binproto) against a scenario set.

    Every rule is applied and every fault reported (grouped by code, counted,
    the first `max_listed` of each code in full): container safety, each shard
    a SimAgentsChallengeSubmission, metadata, scenario coverage, and per
    scenario 32 joint scenes of exactly the sim agents with 80 finite values in
    center_x, center_y, center_z and heading (sim agents), or 91 finite values
    in those and in positive length, width and height, and an object type
    (`challenge="scenario_gen"`).

    scenarios: scenario files / folders / globs, or a ScenarioIndex.
    submission: its path, or an open `parse.submission_source.SubmissionSource`: validation walks it
      and records where each scenario of a readable shard is, for the stages after it.
    limits: how far the submission may expand (`parse.limits.InputLimits`: sizes, members, messages);
      a `SubmissionSource` brings its own.
    progress: called with 1 after each submitted scenario is checked.
    sim_agents: precomputed `load_sim_agents(scenarios)`, to skip reading the scenarios again.
    workers: processes checking shards in parallel (the report is the same for any count).
    executor: where to check the shards (`runtime.executors`; default: `workers` local processes).
    metadata_checks: "error" (the challenge server's rules: a metadata gap makes the submission
      invalid) or "warn" (the same findings as warnings, for local scoring).
    Raises ScenarioSetError when the scenario set cannot be read, FileNotFoundError
    when the submission path does not exist (both usage errors, not findings).
    """
    start = time.perf_counter()
    executor = executor or LocalExecutor(workers, warm_up=compile_walks)  # once here, not in each worker
    agents = sim_agents if sim_agents is not None else load_sim_agents(scenarios, executor=executor)
    challenge = challenges.as_challenge(challenge)
    source = submission if isinstance(submission, SubmissionSource) else SubmissionSource(submission, limits)
    report = ValidationReport(str(source), max_listed=max_listed, challenge=challenge.value)
    report.stats.scenarios_expected = len(agents)
    if metadata_checks not in METADATA_CHECKS:
        raise ValueError(f"metadata_checks must be one of {', '.join(METADATA_CHECKS)}, not {metadata_checks!r}")
    run = _Validation(agents, report, progress, metadata_checks, source.limits.max_scenarios)
    if not source.path.exists():
        raise FileNotFoundError(f"{source}: no such submission file or folder")
    # Workers of this host read an archive's members from scratch files; other nodes get their bytes.
    shards = source.shards(
        problems=lambda problem: report.add(_container_finding(problem)),
        members_in_memory=not isinstance(executor, LocalExecutor),
    )
    listed: collections.deque = collections.deque()  # the names of the shards in flight

    def remember(refs: Iterable[ShardRef]) -> Iterator[ShardRef]:
        for ref in refs:
            listed.append(ref.name)
            yield ref

    try:
        for result in _shard_results(remember(shards), agents, max_listed, executor, challenge, source.limits):
            run.merge(result)
            name = listed.popleft()  # results come back in shard order
            if result.readable:
                source.record(name, ((sid, span) for (_, sid), span in zip(result.entries, result.spans)))
            source.release(name)
    finally:
        if source is not submission:  # opened here: its scratch files go with it
            source.close()
    report.extend(rules.check_overlap(len(agents), run.first_seen, agents))
    missing = rules.check_missing_scenarios(agents, run.first_seen)
    # Every missing-scenario finding names its scenario.
    report.missing_scenarios = [f.scenario_id for f in missing if f.scenario_id is not None]
    report.extend(missing)
    report.stats.scenarios_valid = sum(
        1 for sid in run.first_seen if sid in agents and sid not in report.invalid_scenarios
    )
    report.stats.elapsed_s = time.perf_counter() - start
    return report
