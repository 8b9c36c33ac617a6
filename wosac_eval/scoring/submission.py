"""Score a whole submission against a scenario set, streaming shard by shard.

The submission is validated first (the same rules as `wosac-eval validate`);
an invalid one is refused unless partial scoring is asked for, in which case
every skipped scenario is listed with its reason. Scenarios are then scored
in submission order, in worker processes when `workers > 1`, holding at most a
few scenarios in memory at a time. With `backend="jax"` the features are
computed by the jitted kernels (`wosac_eval.backends.jax_backend`), a few
scenarios per call when `workers == 1`; results are the same.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator

from wosac_eval.allocator import keep_freed_memory
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.scenario import ScenarioArrays, scenario_arrays
from wosac_eval.backends import check_backend
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.config import SimAgentMetricsConfig, load_config
from wosac_eval.metrics.scenario_metrics import aggregate_metrics, bucket_metrics, scenario_metrics
from wosac_eval.parse.archive import iter_submission_shards, parse_submission_shard
from wosac_eval.parse.errors import ParseError
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.parse.wire import field_spans
from wosac_eval.processes import worker_pool
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


def _checked_inputs(scenario, rollouts):
    arrays = scenario if isinstance(scenario, ScenarioArrays) else scenario_arrays(scenario)
    if rollouts.scenario_id != arrays.scenario_id:
        raise ValueError(f"rollouts are for scenario {rollouts.scenario_id!r}, "
                         f"not {arrays.scenario_id!r}")
    return arrays


def _unscorable(arrays: ScenarioArrays, error: Exception) -> ValueError:
    # e.g. a scenario without road edges, or rollouts missing an evaluated object
    return ValueError(f"scenario {arrays.scenario_id}: cannot be scored: {error}")


def score_scenario(scenario: scenario_pb2.Scenario | ScenarioArrays,
                   rollouts: sim_agents_submission_pb2.ScenarioRollouts,
                   config: str | PathLike | SimAgentMetricsConfig = "2025", *,
                   backend: str = "numpy") -> dict:
    """Official `SimAgentMetrics` fields of one scenario, plus its `scenario_id`.

    Args:
      scenario: the logged `Scenario` (or its `ScenarioArrays`).
      rollouts: the 32 simulated joint scenes for it.
      config: a preset name, a textproto path or a `SimAgentMetricsConfig`.
      backend: "numpy" or "jax" (needs the `jax` extra); same results.
    """
    check_backend(backend)
    config = config if isinstance(config, SimAgentMetricsConfig) else load_config(config)
    arrays = _checked_inputs(scenario, rollouts)
    try:
        if backend == "jax":
            from wosac_eval.backends import jax_backend
            log, sim = jax_backend.scenario_features(arrays, rollout_arrays(rollouts))
        else:
            log, sim = scenario_features(arrays, rollout_arrays(rollouts))
    except (ValueError, KeyError) as error:
        raise _unscorable(arrays, error) from error
    return {"scenario_id": arrays.scenario_id, **scenario_metrics(config, log, sim)}


def score_scenarios_jax(pairs, config: str | PathLike | SimAgentMetricsConfig = "2025",
                        max_batch: int = 8) -> list[dict]:
    """`score_scenario` with the jax backend for many (scenario, rollouts) pairs at once.

    Scenarios of the same size bucket share one `vmap`ped call.
    """
    from wosac_eval.backends import jax_backend
    config = config if isinstance(config, SimAgentMetricsConfig) else load_config(config)
    prepared = []
    for scenario, rollouts in pairs:
        arrays = _checked_inputs(scenario, rollouts)
        try:
            prepared.append(jax_backend.prepare(arrays, rollout_arrays(rollouts)))
        except (ValueError, KeyError) as error:
            raise _unscorable(arrays, error) from error
    features = jax_backend.prepared_features(prepared, max_batch=max_batch)
    return [{"scenario_id": p.scenario_id, **scenario_metrics(config, log, sim)}
            for p, (log, sim) in zip(prepared, features)]


def summarize(config: SimAgentMetricsConfig, per_scenario: list[dict]) -> dict:
    """Aggregate (mean over scenarios) and bucketed metrics of scored scenarios."""
    aggregate = aggregate_metrics(per_scenario)
    return {"aggregate": aggregate, "buckets": bucket_metrics(config, aggregate)}


# Worker-process state: the config and the scenario index, set once per process.
_WORKER: dict = {}


def _init_worker(config_bytes: bytes, index: ScenarioIndex, backend: str = "numpy") -> None:
    keep_freed_memory()
    _WORKER["config"] = SimAgentMetricsConfig.FromString(config_bytes)
    _WORKER["index"] = index
    _WORKER["backend"] = backend


def _score_task(scenario_id: str, rollouts_bytes: bytes) -> dict:
    rollouts = sim_agents_submission_pb2.ScenarioRollouts.FromString(rollouts_bytes)
    scenario = _WORKER["index"].load(scenario_id)
    return score_scenario(scenario, rollouts, _WORKER["config"], backend=_WORKER["backend"])


def _score_batch(tasks: list[tuple[str, bytes]]) -> list[dict]:
    """Several scenarios in one jax-backend call (their features are batched)."""
    pairs = [(_WORKER["index"].load(sid), sim_agents_submission_pb2.ScenarioRollouts.FromString(data))
             for sid, data in tasks]
    return score_scenarios_jax(pairs, _WORKER["config"])


def _split_shard(name: str, raw: bytes) -> list[tuple[str, bytes]]:
    """(scenario_id, serialized ScenarioRollouts) of every scenario of a shard.

    The shard is split at the wire level (`field_spans`: scenario_rollouts is
    field 1 of the submission, scenario_id field 1 of each element), so the
    parent process hands the workers bytes without parsing and re-serialising
    them; anything unexpected falls back to a full parse.
    """
    try:
        items = []
        for start, end in field_spans(raw, 1):
            data = raw[start:end]
            ids = field_spans(data, 1)  # a repeated singular field: the last one counts, as in a parse
            items.append((data[ids[-1][0]:ids[-1][1]].decode("utf-8") if ids else "", data))
        return items
    except (ValueError, UnicodeDecodeError):
        try:
            submission = parse_submission_shard(name, raw)
        except ParseError:
            return []
        return [(r.scenario_id, r.SerializeToString()) for r in submission.scenario_rollouts]


def _rollouts_to_score(submission_path: PathLike, index: ScenarioIndex, report) -> Iterator[tuple[str, bytes]]:
    """(scenario_id, serialized ScenarioRollouts) of every valid scenario, once each."""
    seen: set[str] = set()
    # Shards validation could not parse hold no valid scenario (only reached in partial mode).
    unparseable = {finding.shard for finding in report.findings("shard.unparseable")}
    for shard_name, raw in iter_submission_shards(submission_path):
        if shard_name in unparseable:
            continue
        for sid, data in _split_shard(shard_name, raw):
            if sid in seen or sid not in index or not report.is_scenario_valid(sid):
                continue
            seen.add(sid)
            yield sid, data


_JAX_BATCH = 8  # scenarios per jax-backend call in a single process


def _map_ordered(tasks: Iterable[tuple[str, bytes]], workers: int, config: SimAgentMetricsConfig,
                 index: ScenarioIndex, backend: str = "numpy") -> Iterator[dict]:
    """Scores tasks in order; with workers, keeps only a bounded number in flight."""
    if workers <= 1:
        _init_worker(config.SerializeToString(), index, backend)
        if backend == "jax":
            batch: list = []
            for task in tasks:
                batch.append(task)
                if len(batch) == _JAX_BATCH:
                    yield from _score_batch(batch)
                    batch = []
            if batch:
                yield from _score_batch(batch)
            return
        for sid, data in tasks:
            yield _score_task(sid, data)
        return
    # JAX runs threads once started: its workers are spawned, not forked.
    with worker_pool(workers, force_spawn=backend == "jax", initializer=_init_worker,
                     initargs=(config.SerializeToString(), index, backend)) as pool:
        pending = []
        for task in tasks:
            pending.append(pool.submit(_score_task, *task))
            if len(pending) >= 4 * workers:
                yield pending.pop(0).result()
        for future in pending:
            yield future.result()


def score_submission(scenario_paths: PathLike | Iterable[PathLike], submission_path: PathLike,
                     config: str | PathLike = "2025", *, workers: int = 1, allow_partial: bool = False,
                     progress: Progress | None = None, backend: str = "numpy") -> dict:
    """Validate and score a submission; returns the `result.json` document.

    Args:
      scenario_paths: TFRecord files, folders or globs of `Scenario`s.
      submission_path: a `.binproto`, a folder of shards, or a `.tar`/`.tar.gz`.
      config: preset name ("2025", "2024", "2023") or a textproto path.
      workers: worker processes (results are identical for any count).
      allow_partial: score the valid scenarios of an invalid submission
        instead of refusing it; skipped scenarios are listed in `skipped`.
      progress: called as `progress(done, total)` after each scored scenario.
      backend: "numpy" or "jax" (needs the `jax` extra); results are identical.

    Raises:
      InvalidSubmissionError: the submission is invalid and `allow_partial` is False.
    """
    check_backend(backend)
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
                               metrics_config, index, backend):
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
