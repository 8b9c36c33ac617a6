"""Score a whole submission against a scenario set: the pipeline every front calls.

stream -> validate -> schedule -> assemble, on an executor (`runtime.executors`:
this process, worker processes of this host, or a Ray cluster):

1. index the scenario set (scenario_id -> file and offset);
2. validate the submission (the same rules and report as `wosac-eval validate`),
   one task per shard; an invalid submission is refused before any scoring,
   unless partial scoring is asked for (then every skipped scenario is listed);
3. score the valid scenarios, a few per task (`ScoringChunk`): workers read
   their scenarios and rollouts themselves (byte ranges of the shard files, for
   a folder or an uncompressed shard file) or receive the rollouts' bytes (for an
   archive, which this process streams once more);
4. assemble the per-scenario results, in submission order, into the result
   document (`scoring.result`): identical whatever the engine, the number of
   workers or nodes, and the order in which the work finishes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from wosac_eval.analysis import criticality_cache
from wosac_eval.analysis.criticality_scores import BehaviourHistogram
from wosac_eval.analysis.scenario_set_criticality import scenario_set_criticality, select_scenarios
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.scenario import record_arrays
from wosac_eval.challenges import Challenge, ChallengeLike
from wosac_eval.metrics.config import SimAgentMetricsConfig
from wosac_eval.options import Backend, Engine
from wosac_eval.parse.decode import decode_message
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.parse.submission_source import RolloutsLocator, SubmissionSource, read_locator
from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.runtime.allocator import keep_freed_memory
from wosac_eval.runtime.executors import Executor, make_executor
from wosac_eval.scoring.evaluation import Evaluation, evaluation_for
from wosac_eval.scoring.journal import ScoringJournal, members_budget, members_path, remove_journal, run_identity
from wosac_eval.scoring.objects import format_of, write_objects
from wosac_eval.scoring.result import result_document
from wosac_eval.scoring.scenario import prepare_jax_item, score_jax_items, score_scenario
from wosac_eval.scoring.warm_up import compile_loops
from wosac_eval.validate import validate_submission
from wosac_eval.validate.findings import ValidationReport

PathLike = str | os.PathLike
Progress = Callable[[int, int], None]
SCENARIOS_PER_TASK = 8  # scenarios scored by one task (one jax-backend batch)


class InvalidSubmissionError(ValueError):
    """The submission failed validation; `.report` says every reason. `.metadata` is True when it is
    refused for its metadata, which partial scoring never goes past."""

    def __init__(self, report: ValidationReport) -> None:
        self.report = report
        self.metadata = report.metadata_error_count > 0
        # What is wrong, in a few words (the service's job says "the submission is invalid: <reason>").
        self.reason = f"{report.error_count} error(s)" + (
            f", {report.metadata_error_count} of them in its metadata (partial scoring never goes past those)"
            if self.metadata
            else ""
        )
        super().__init__(f"invalid submission: {self.reason}; run `wosac-eval validate` for the full report")


def refuses(report: ValidationReport, allow_partial: bool) -> bool:
    """Whether an invalid submission is refused: always without partial scoring; with it, for metadata
    errors (partial scoring scores the valid scenarios and lists the others, never ignores the metadata)."""
    return not report.ok and (not allow_partial or report.metadata_error_count > 0)


@dataclasses.dataclass(frozen=True)
class ScoringContext:
    """What every worker needs (sent once per worker process).

    Attributes:
      config: the serialized `SimAgentMetricsConfig`.
      challenge: the challenge.
      backend: `Backend` numpy or jax.
      index: where each scenario of the set is.
      analysis: add each scenario's criticality, driving scores and per-type metrics to its row.
      per_object: add each scenario's per-object values (`objects`) to its row.
    """

    config: bytes
    challenge: Challenge
    backend: Backend
    index: ScenarioIndex
    analysis: bool = True
    per_object: bool = False


@dataclasses.dataclass(frozen=True)
class ScoringChunk:
    """A few scenarios to score: (scenario_id, rollouts) pairs, where the rollouts are the serialized
    `ScenarioRollouts`, or (path, offset, size) of those bytes in a file every worker can read."""

    items: tuple


def _pairs(context: ScoringContext, chunk: ScoringChunk) -> list[tuple]:
    """The chunk's (ScenarioArrays, RolloutArrays, criticality, cache key), read by the worker: the rollouts
    are parsed (which refuses bytes that are not a message) and their arrays read from the bytes they were
    parsed from; the scenario's arrays are read from its record's bytes (`record_arrays`: the operator's
    scenario set is not parsed whole for each submission). With the analysis, the scene's criticality is
    the one an earlier run kept (`analysis.criticality_cache`, under the record's key), None when none did;
    without it both are None."""
    pairs = []
    for sid, locator in chunk.items:
        record = context.index.load_record(sid)
        scenario = record_arrays(record, context.index.source(sid))
        key = criticality_cache.record_key(sid, record) if context.analysis else None
        known = criticality_cache.cached(key) if key is not None else None
        data = read_locator(locator)
        rollouts = decode_message(sim_agents_submission_pb2.ScenarioRollouts, data)
        pairs.append((scenario, rollout_arrays(rollouts, context.challenge, data), known, key))
    return pairs


def _keep_criticality(pairs: list[tuple], criticality: list) -> None:
    """Keeps the scenes' criticality computed now (`analysis.criticality_cache`) for later runs."""
    criticality_cache.keep(
        [
            (key, computed)
            for (_, _, known, key), computed in zip(pairs, criticality)
            if known is None and key is not None and computed is not None
        ]
    )


def score_chunk(context: ScoringContext, chunk: ScoringChunk) -> list[dict]:
    """Scores the scenarios of a chunk (a worker task); results in chunk order."""
    config = SimAgentMetricsConfig.FromString(context.config)
    pairs = _pairs(context, chunk)
    if context.backend is Backend.JAX:
        items = _jax_items(context, pairs)
        rows = list(
            score_jax_items(
                items, config, challenge=context.challenge, analysis=context.analysis, per_object=context.per_object
            )
        )
    else:
        rows = [
            score_scenario(
                scenario,
                rollouts,
                config,
                challenge=context.challenge,
                analysis=context.analysis,
                per_object=context.per_object,
                criticality=known,
            )
            for scenario, rollouts, known, _ in pairs
        ]
        if context.analysis:
            _keep_criticality(pairs, [row.get("criticality") for row in rows])
    return rows


def prepare_chunk(context: ScoringContext, chunk: ScoringChunk) -> list:
    """The host part of jax-backend scoring of a chunk (a worker task): `scoring.scenario.JaxItem`s."""
    return _jax_items(context, _pairs(context, chunk))


def _jax_items(context: ScoringContext, pairs: list[tuple]) -> list:
    items = [
        prepare_jax_item(scenario, rollouts, context.challenge, context.analysis, known)
        for scenario, rollouts, known, _ in pairs
    ]
    if context.analysis:
        _keep_criticality(pairs, [item.criticality for item in items])
    return items


def _jax_pipeline(executor: Any, chunks: Any, context: ScoringContext, config: Any) -> Iterator[list[dict]]:
    """Rows, one at a time, in order: workers parse and prepare, this process feeds the device."""
    items = (item for prepared in executor.imap(prepare_chunk, chunks, context) for item in prepared)
    for row in score_jax_items(
        items, config, challenge=context.challenge, analysis=context.analysis, per_object=context.per_object
    ):
        yield [row]


def _scored_rollouts(
    source: SubmissionSource, index: ScenarioIndex, report: Any, selected: set[str] | None, done: Any = ()
) -> Iterator[tuple[str, RolloutsLocator | None]]:
    """(scenario_id, rollouts locator) of every valid (and selected) scenario, once each, in submission order;
    the locator is None for a scenario in `done` (a resumed run does not read what it finished)."""
    seen: set[str] = set()
    for sid, locator in source.rollouts_locators(lambda sid: sid not in done):
        if sid in seen or sid not in index or not report.is_scenario_valid(sid):
            continue
        seen.add(sid)
        if selected is None or sid in selected:
            yield sid, locator


def _chunks(items: Iterable, size: int) -> Iterator[ScoringChunk]:
    batch: list = []
    for item in items:
        batch.append(item)
        if len(batch) == size:
            yield ScoringChunk(tuple(batch))
            batch = []
    if batch:
        yield ScoringChunk(tuple(batch))


def score_submission(
    scenario_paths: PathLike | Iterable[PathLike] | ScenarioIndex,
    submission: PathLike | SubmissionSource,
    config: str | PathLike | None = None,
    *,
    challenge: ChallengeLike | None = None,
    progress: Progress | None = None,
    evaluation: Evaluation | None = None,
    journal: PathLike | None = None,
    **options: Any,
) -> dict:
    """Validate and score a submission; returns the `result.json` document.

    Args:
      scenario_paths: TFRecord files, folders or globs of `Scenario`s, or a `ScenarioIndex` of them.
      submission: a `.binproto`, a folder of shards, a `.tar`/`.tar.gz`, or an open `SubmissionSource`
        (then the stages after validation read what it recorded: see `parse.submission_source`).
      config: preset name ("2025", "2024", "2023", "scenario_gen_2025") or a
        textproto path; None: the challenge's current leaderboard config. A preset of the other
        challenge is refused.
      challenge: "sim_agents" (default) or "scenario_gen".
      progress: called as `progress(done, total)` after each scored scenario.
      evaluation: the challenge, config and options, already resolved (`scoring.evaluation.resolve_evaluation`);
        a challenge, config or option also given must agree with it (else a ValueError names each).
      **options: the run's options by name (`scoring.evaluation.RunOptions`: backend "numpy" or "jax",
        engine "local" or "ray", ray_address, workers, allow_partial, metadata_checks "warn" or "error",
        select "top:0.1" or "top:100", analysis, limits, per_object, objects), checked before any work.
        per_object: also give every evaluated object's values (`scoring.scenario.object_records`): with
        `objects`, streamed to that file (`.jsonl` or `.parquet`, `scoring.objects`), never all held in
        memory, and the document's `per_object` names it (write the result beside it); without, each row
        carries its `objects` (for small sets: they are all in the returned document). The objects come
        from the journal (a temporary one beside the file when there is no `journal`), so a resumed run
        writes the same file.
      journal: a file where each finished scenario's row is recorded as it is scored
        (`scoring.journal`); when it holds rows of the same run (same inputs, config and options),
        those scenarios are not scored again, and the result is the one an uninterrupted run gives.
        It is left in place (with its validation, PATH.validated, and an archive's last members,
        PATH.members): remove them once the result is stored
        (`scoring.journal.remove_journal`).
    Raises:
      InvalidSubmissionError: the submission is invalid and `allow_partial` is False.
      ValueError: an argument cannot be resolved (unknown config, a preset of the other challenge...).
    """
    evaluation = evaluation_for("score_submission", evaluation, challenge, config, options)
    run = evaluation.options
    # The engine first: an unreachable cluster is reported before any long work.
    executor = make_executor(
        run.engine,
        workers=run.workers,
        ray_address=run.ray_address,
        force_spawn=run.backend is Backend.JAX,
        initializer=keep_freed_memory,
        warm_up=compile_loops,  # numba's loops compiled once here, not in every worker of a fresh installation
    )
    with _opened(submission, journal, run.limits) as source:
        index = scenario_paths if isinstance(scenario_paths, ScenarioIndex) else ScenarioIndex(scenario_paths)
        objects = run.objects
        if objects is not None:
            format_of(objects)  # a suffix that chooses no format is refused before any work
        temporary = journal is None  # the objects wait in a journal of this run only
        if journal is None:
            if objects is None:
                return _score(index, source, evaluation, executor, progress, None)
            journal = Path(objects).with_name(f".{Path(objects).name}.{os.getpid()}.journal")
        try:
            with ScoringJournal(journal, run_identity(evaluation, source.path, index.paths)) as record:
                return _score(index, source, evaluation, executor, progress, record)
        finally:
            if temporary:
                remove_journal(journal)


def _opened(
    submission: PathLike | SubmissionSource, journal: PathLike | None, limits: InputLimits
) -> contextlib.AbstractContextManager[SubmissionSource]:
    """The submission to read, as a context: a handle the caller opened stays open; with a journal, an
    archive's last members are kept beside it, so a run resumed late need not decompress the archive up
    to them (`scoring.journal`)."""
    if isinstance(submission, SubmissionSource):
        return contextlib.nullcontext(submission)
    if journal is not None:
        tail_dir, tail_bytes = members_path(journal), members_budget(submission, journal)
        return SubmissionSource(submission, limits, tail_dir=tail_dir, tail_bytes=tail_bytes)
    return SubmissionSource(submission, limits)


def _selection(
    evaluation: Evaluation, index: ScenarioIndex, executor: Executor
) -> tuple[dict | None, BehaviourHistogram | None, set | None]:
    """(what the result says of the selection, the criticality histogram, the selected ids), or Nones."""
    rule = evaluation.options.select
    if rule is None:
        return None, None, None
    ranked = scenario_set_criticality(index, executor=executor)
    selected = set(select_scenarios(ranked["scenarios"], rule))
    selection = {
        "rule": rule,
        "scenarios": len(selected),
        "of": ranked["num_scenarios"],
        "min_criticality": min(r["score"] for r in ranked["scenarios"] if r["scenario_id"] in selected),
    }
    return selection, ranked["histogram"], selected


def _validated(
    index: ScenarioIndex,
    source: SubmissionSource,
    evaluation: Evaluation,
    executor: Any,
    journal: ScoringJournal | None,
) -> Any:
    """The submission's validation report, refusing an invalid one; from the journal when an earlier run
    of the same inputs passed it (a resumed run does not walk the whole submission again)."""
    kept = None if journal is None else journal.validation()
    if kept is not None:
        report, records = kept
        source.restore_records(records)
        return report
    report = validate_submission(
        index,
        source,
        challenge=evaluation.challenge,
        executor=executor,
        metadata_checks=evaluation.options.metadata_checks,
    )
    if refuses(report, evaluation.options.allow_partial):
        source.drop_tail()  # the archive members kept for scoring: none will be
        raise InvalidSubmissionError(report)
    records = source.records()
    if journal is not None and records is not None:
        journal.keep_validation(report, records)
    return report


def _score(
    index: ScenarioIndex,
    source: SubmissionSource,
    evaluation: Evaluation,
    executor: Any,
    progress: Progress | None,
    journal: ScoringJournal | None,
) -> dict:
    """Validate (recording where each scenario is), select, score on the executor (but what the journal
    holds), assemble; per-object values go through the journal (see `score_submission`)."""
    per_object, objects = evaluation.options.per_object, evaluation.options.objects
    report = _validated(index, source, evaluation, executor, journal)
    selection, histogram, selected = _selection(evaluation, index, executor)
    total = sum(1 for sid in index if report.is_scenario_valid(sid) and (selected is None or sid in selected))
    context = ScoringContext(
        config=evaluation.config.SerializeToString(),
        challenge=evaluation.challenge,
        backend=evaluation.options.backend,
        index=index,
        analysis=evaluation.options.analysis,
        per_object=per_object,
    )
    done = {} if journal is None else journal.done
    order: list[str] = []  # every scored scenario, in submission order (the rows' order)

    def to_score() -> Iterator[tuple[str, RolloutsLocator | None]]:
        for sid, locator in _scored_rollouts(source, index, report, selected, done):
            order.append(sid)
            if sid not in done:
                yield sid, locator

    chunks = _chunks(to_score(), SCENARIOS_PER_TASK)
    rows = dict(done)
    if progress is not None:
        progress(len(rows), total)
    if evaluation.options.backend is Backend.JAX and evaluation.options.engine is Engine.LOCAL:
        # Pipelined: workers parse and prepare on the host, this process keeps the device busy.
        scored = _jax_pipeline(executor, chunks, context, evaluation.config)
    else:
        scored = executor.imap(score_chunk, chunks, context)
    for results in scored:
        if journal is not None:
            journal.record(results)
            for row in results:  # in the journal: not held here (objects_of reads them back)
                row.pop("objects", None)
        rows.update((row["scenario_id"], row) for row in results)
        if progress is not None:
            progress(len(rows), total)
    per_scenario = [rows[sid] for sid in order]
    if not per_scenario:
        raise (
            InvalidSubmissionError(report)
            if not report.ok
            else ValueError("the submission has no scenario in common with the scenario set")
        )
    if per_object and objects is None and journal is not None:  # inline: the rows carry them
        for sid, row in zip(order, per_scenario):
            row["objects"] = journal.objects_of(sid)
    written = None
    if objects is not None:
        assert journal is not None  # `score_submission` records the objects in one (a temporary one at least)
        written = write_objects((journal.objects_of(sid) for sid in order), objects)
    document = result_document(
        evaluation.challenge,
        evaluation.config_name,
        evaluation.config,
        per_scenario,
        report,
        selection=selection,
        selected=selected,
        histogram=histogram,
    )
    if objects is not None:  # then `written` is their count
        document["per_object"] = {"objects": Path(objects).name, "format": format_of(objects), "num_objects": written}
    return document
