"""Score a whole submission against a scenario set, streaming shard by shard.

The submission is validated first (the same rules as `wosac-eval validate`);
an invalid one is refused unless partial scoring is asked for, in which case
every skipped scenario is listed with its reason. Scenarios are then scored
in submission order, in worker processes when `workers > 1`, holding at most a
few scenarios in memory at a time.
"""
from __future__ import annotations

import concurrent.futures as futures
import os
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from wosac_eval.allocator import keep_freed_memory
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.scenario import ScenarioArrays, scenario_arrays
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.config import SimAgentMetricsConfig, load_config
from wosac_eval.metrics.scenario_metrics import aggregate_metrics, bucket_metrics, scenario_metrics
from wosac_eval.parse.archive import iter_submission_shards, parse_submission_shard
from wosac_eval.parse.errors import ParseError
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2
from wosac_eval.validate import validate_submission

PathLike = str | os.PathLike
Progress = Callable[[int, int], None]


class InvalidSubmissionError(ValueError):
    """The submission failed validation; `.report` says every reason."""

    def __init__(self, report):
        self.report = report
        super().__init__(f"invalid submission: {report.error_count} error(s); "
                         f"run `wosac-eval validate` for the full report")


def score_scenario(scenario: scenario_pb2.Scenario | ScenarioArrays,
                   rollouts: sim_agents_submission_pb2.ScenarioRollouts,
                   config: str | PathLike | SimAgentMetricsConfig = "2025") -> dict:
    """Official `SimAgentMetrics` fields of one scenario, plus its `scenario_id`.

    Args:
      scenario: the logged `Scenario` (or its `ScenarioArrays`).
      rollouts: the 32 simulated joint scenes for it.
      config: a preset name, a textproto path or a `SimAgentMetricsConfig`.
    """
    config = config if isinstance(config, SimAgentMetricsConfig) else load_config(config)
    arrays = scenario if isinstance(scenario, ScenarioArrays) else scenario_arrays(scenario)
    if rollouts.scenario_id != arrays.scenario_id:
        raise ValueError(f"rollouts are for scenario {rollouts.scenario_id!r}, "
                         f"not {arrays.scenario_id!r}")
    try:
        log, sim = scenario_features(arrays, rollout_arrays(rollouts))
    except (ValueError, KeyError) as error:
        # e.g. a scenario without road edges, or rollouts missing an evaluated object
        raise ValueError(f"scenario {arrays.scenario_id}: cannot be scored: {error}") from error
    return {"scenario_id": arrays.scenario_id, **scenario_metrics(config, log, sim)}


def summarize(config: SimAgentMetricsConfig, per_scenario: list[dict]) -> dict:
    """Aggregate (mean over scenarios) and bucketed metrics of scored scenarios."""
    aggregate = aggregate_metrics(per_scenario)
    return {"aggregate": aggregate, "buckets": bucket_metrics(config, aggregate)}


# Worker-process state: the config and the scenario index, set once per process.
_WORKER: dict = {}


def _init_worker(config_bytes: bytes, index: ScenarioIndex) -> None:
    keep_freed_memory()
    _WORKER["config"] = SimAgentMetricsConfig.FromString(config_bytes)
    _WORKER["index"] = index


def _score_task(scenario_id: str, rollouts_bytes: bytes) -> dict:
    rollouts = sim_agents_submission_pb2.ScenarioRollouts.FromString(rollouts_bytes)
    scenario = _WORKER["index"].load(scenario_id)
    return score_scenario(scenario, rollouts, _WORKER["config"])


def _rollouts_to_score(submission_path: PathLike, index: ScenarioIndex, report) -> Iterator[tuple[str, bytes]]:
    """(scenario_id, serialized ScenarioRollouts) of every valid scenario, once each."""
    seen: set[str] = set()
    for shard_name, raw in iter_submission_shards(submission_path):
        try:
            submission = parse_submission_shard(shard_name, raw)
        except ParseError:
            continue  # already reported by validation; only reached in partial mode
        for rollouts in submission.scenario_rollouts:
            sid = rollouts.scenario_id
            if sid in seen or sid not in index or not report.is_scenario_valid(sid):
                continue
            seen.add(sid)
            yield sid, rollouts.SerializeToString()


def _map_ordered(tasks: Iterable[tuple[str, bytes]], workers: int, config: SimAgentMetricsConfig,
                 index: ScenarioIndex) -> Iterator[dict]:
    """Scores tasks in order; with workers, keeps only a bounded number in flight."""
    if workers <= 1:
        _init_worker(config.SerializeToString(), index)
        for sid, data in tasks:
            yield _score_task(sid, data)
        return
    with futures.ProcessPoolExecutor(max_workers=workers, initializer=_init_worker,
                                     initargs=(config.SerializeToString(), index)) as pool:
        pending = []
        for task in tasks:
            pending.append(pool.submit(_score_task, *task))
            if len(pending) >= 4 * workers:
                yield pending.pop(0).result()
        for future in pending:
            yield future.result()


def score_submission(scenario_paths: PathLike | Iterable[PathLike], submission_path: PathLike,
                     config: str | PathLike = "2025", *, workers: int = 1, allow_partial: bool = False,
                     progress: Progress | None = None) -> dict:
    """Validate and score a submission; returns the `result.json` document.

    Args:
      scenario_paths: TFRecord files, folders or globs of `Scenario`s.
      submission_path: a `.binproto`, a folder of shards, or a `.tar`/`.tar.gz`.
      config: preset name ("2025", "2024", "2023") or a textproto path.
      workers: worker processes (results are identical for any count).
      allow_partial: score the valid scenarios of an invalid submission
        instead of refusing it; skipped scenarios are listed in `skipped`.
      progress: called as `progress(done, total)` after each scored scenario.

    Raises:
      InvalidSubmissionError: the submission is invalid and `allow_partial` is False.
    """
    metrics_config = load_config(config)
    index = ScenarioIndex(scenario_paths)
    report = validate_submission(index, submission_path, workers=workers)
    if not report.ok and not allow_partial:
        raise InvalidSubmissionError(report)
    skipped = [{"scenario_id": sid, "reason": reason}
               for sid, reason in sorted(report.skipped_scenarios.items())]
    total = sum(1 for sid in index if report.is_scenario_valid(sid))
    per_scenario = []
    if progress is not None:
        progress(0, total)
    for result in _map_ordered(_rollouts_to_score(submission_path, index, report), workers,
                               metrics_config, index):
        per_scenario.append(result)
        if progress is not None:
            progress(len(per_scenario), total)
    if not per_scenario:
        raise InvalidSubmissionError(report) if not report.ok else ValueError(
            "the submission has no scenario in common with the scenario set")
    return {"config": str(config), "num_scenarios": len(per_scenario),
            "scenarios": per_scenario, **summarize(metrics_config, per_scenario),
            "skipped": skipped, "validation": {"errors": report.error_count,
                                               "warnings": report.warning_count}}
