"""Validate a whole submission against a scenario set, streaming shard by shard.

Memory stays bounded: from the scenario set only the sim agent ids of each
scenario are kept (a few hundred bytes per scenario: `validate.scenario_set`); a shard
is read from its file one scenario at a time (`validate.shard_checks`), so a process holds
one scenario's bytes and message, whatever the shard's size; the report keeps counts
and the first findings of each kind. Here the shards' results are merged, in shard
order, and the rules that span shards are applied (metadata consistency, duplicate,
unknown and missing scenarios).
"""

from __future__ import annotations

import collections
import dataclasses
import os
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.parse.decompress import ArchiveNameWarning, UncompressedTarWarning
from wosac_eval.parse.errors import SizeLimitError, UnsafeArchiveMemberError
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.parse.shard_walk import NotAShardError, ShardRef
from wosac_eval.parse.submission_source import SubmissionSource
from wosac_eval.parse.wire_walks import compile_walks
from wosac_eval.runtime.executors import Executor, LocalExecutor
from wosac_eval.validate import coverage_rules, metadata_rules
from wosac_eval.validate.findings import WARNING, Finding, Location, ValidationReport, make_finding
from wosac_eval.validate.scenario_set import load_sim_agents
from wosac_eval.validate.shard_checks import ShardResult, check_shard

PathLike = str | os.PathLike


METADATA_CHECKS = ("error", "warn")  # how metadata findings count: as the challenge server, or as warnings


@dataclasses.dataclass(frozen=True)
class ValidationOptions:
    """What a validation judges by, and how much of it the report lists.

    Attributes:
      challenge: whose rules: "sim_agents" (80 future steps) or "scenario_gen" (91 steps, boxes and
        types); a `Challenge` here.
      metadata_checks: "error" (the challenge server's rules: a metadata gap makes the submission
        invalid) or "warn" (the same findings as warnings, for local scoring).
      limits: how far the submission may expand (`parse.limits.InputLimits`: sizes, members, messages;
        None: the defaults); a `SubmissionSource` brings its own.
      max_listed: findings kept in full per code (the rest are counted).
    """

    challenge: challenges.Challenge = challenges.Challenge.SIM_AGENTS
    metadata_checks: str = "error"
    limits: InputLimits | None = None
    max_listed: int = 20

    def __post_init__(self) -> None:
        object.__setattr__(self, "challenge", challenges.as_challenge(self.challenge))
        if self.metadata_checks not in METADATA_CHECKS:
            raise ValueError(
                f"metadata_checks must be one of {', '.join(METADATA_CHECKS)}, not {self.metadata_checks!r}"
            )
        if self.max_listed < 0:
            raise ValueError("max_listed must be >= 0")


_OPTION_NAMES = frozenset(field.name for field in dataclasses.fields(ValidationOptions))


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
    ) -> None:
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
            report.add(make_finding("shard.empty", result.empty_detail, Location(name)))
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
                    metadata_rules.check_metadata_consistency(
                        self.reference_metadata, self.reference_shard, metadata, name
                    )
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
            report.add(coverage_rules.missing_scenario_id(name, index))
            return
        first = self.first_seen.get(scenario_id)
        if first is not None:
            report.add(coverage_rules.duplicate_scenario(scenario_id, name, index, first))
        else:
            self.first_seen[scenario_id] = (name, index)
        if scenario_id not in self.agents:
            report.add(coverage_rules.unknown_scenario(scenario_id, name, index))


def _check_shard_task(shared: tuple, shard: ShardRef) -> ShardResult:
    """`check_shard` in a worker; `shared` is (agents, max_listed, challenge name, limits)."""
    agents, max_listed, challenge, limits = shared
    return check_shard(shard, agents, max_listed, challenge, limits)


def validate_submission(
    scenarios: ScenarioIndex | PathLike | Iterable[PathLike],
    submission: PathLike | SubmissionSource,
    options: ValidationOptions | None = None,
    *,
    progress: Callable[[int], Any] | None = None,
    sim_agents: dict[str, np.ndarray] | None = None,
    workers: int = 1,
    executor: Executor | None = None,
    **option_values: Any,
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
    options: the `ValidationOptions` (challenge, metadata_checks, limits, max_listed); or leave it out
      and name them (`challenge="scenario_gen"`, `limits=InputLimits(...)`...).
    progress: called with 1 after each submitted scenario is checked.
    sim_agents: precomputed `load_sim_agents(scenarios)`, to skip reading the scenarios again.
    workers: processes checking shards in parallel (the report is the same for any count).
    executor: where to check the shards (`runtime.executors`; default: `workers` local processes).
    Raises ScenarioSetError when the scenario set cannot be read, FileNotFoundError
    when the submission path does not exist (both usage errors, not findings).
    """
    options = _options(options, option_values)
    start = time.perf_counter()
    executor = executor or LocalExecutor(workers, warm_up=compile_walks)  # once here, not in each worker
    agents = sim_agents if sim_agents is not None else load_sim_agents(scenarios, executor=executor)
    source = submission if isinstance(submission, SubmissionSource) else SubmissionSource(submission, options.limits)
    report = ValidationReport(str(source), max_listed=options.max_listed, challenge=options.challenge)
    report.stats.scenarios_expected = len(agents)
    run = _Validation(agents, report, progress, options.metadata_checks, source.limits.max_scenarios)
    if not source.path.exists():
        raise FileNotFoundError(f"{source}: no such submission file or folder")
    try:
        _check_shards(source, run, executor, options)
    finally:
        if source is not submission:  # opened here: its scratch files go with it
            source.close()
    _check_coverage(report, agents, run.first_seen)
    report.stats.elapsed_s = time.perf_counter() - start
    return report


def _options(options: ValidationOptions | None, values: dict[str, Any]) -> ValidationOptions:
    """The options given, or those named (the others default); a name that is none is a TypeError."""
    if options is not None and values:
        raise TypeError(f"validate_submission: give options= or the options by name ({', '.join(values)}), not both")
    unknown = sorted(set(values) - _OPTION_NAMES)
    if unknown:
        raise TypeError(
            f"validate_submission() got an unexpected keyword argument {unknown[0]!r} "
            f"(its options: {', '.join(sorted(_OPTION_NAMES))})"
        )
    return options if options is not None else ValidationOptions(**values)


def _check_shards(source: SubmissionSource, run: _Validation, executor: Executor, options: ValidationOptions) -> None:
    """Check every shard with the executor (this process, worker processes or Ray), merge the results in
    shard order, and record where each readable shard's scenarios are in `source`.

    A shard per worker is in flight, and none waiting (an official shard is 300-400 MB decompressed):
    memory stays bounded by a few shards (shards of folders are byte ranges: the workers read them).
    """
    # Workers of this host read an archive's members from scratch files; other nodes get their bytes.
    shards = source.shards(
        problems=lambda problem: run.report.add(_container_finding(problem)),
        members_in_memory=not isinstance(executor, LocalExecutor),
    )
    listed: collections.deque = collections.deque()  # the names of the shards in flight

    def remember(refs: Iterable[ShardRef]) -> Iterator[ShardRef]:
        for ref in refs:
            listed.append(ref.name)
            yield ref

    shared = (run.agents, options.max_listed, options.challenge, source.limits)
    for result in executor.imap(_check_shard_task, remember(shards), shared, ahead=0):
        run.merge(result)
        name = listed.popleft()  # results come back in shard order
        if result.readable:
            source.record(name, ((sid, span) for (_, sid), span in zip(result.entries, result.spans)))
        source.release(name)


def _check_coverage(report: ValidationReport, agents: dict[str, np.ndarray], submitted: dict) -> None:
    """The coverage rules over the whole submission (the scenarios submitted, in order, against the set),
    and the count of valid scenarios."""
    report.extend(coverage_rules.check_overlap(len(agents), submitted, agents))
    missing = coverage_rules.check_missing_scenarios(agents, submitted)
    # Every missing-scenario finding names its scenario.
    report.missing_scenarios = [f.scenario_id for f in missing if f.scenario_id is not None]
    report.extend(missing)
    report.stats.scenarios_valid = sum(1 for sid in submitted if sid in agents and sid not in report.invalid_scenarios)
