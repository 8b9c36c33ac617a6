"""Criticality of a scenario set, without any submission: for curating sets and for `score --select`.

Two passes over the set: each scenario's heuristic criticality (a task per few
scenarios, on the same executors as scoring), then the set's behaviour
histogram and every scenario's rarity against it (`analysis.criticality_scores`).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from collections.abc import Callable, Iterable

import numpy as np

from wosac_eval.analysis import criticality_cache
from wosac_eval.analysis.criticality_features import criticality_features
from wosac_eval.analysis.criticality_scores import (
    LONG_TAIL_QUANTILE,
    scene_criticality,
    set_histogram,
    step_criticality,
    with_rarity,
)
from wosac_eval.arrays.scenario import record_arrays
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.runtime.executors import Executor, make_executor

PathLike = str | os.PathLike
SCENARIOS_PER_TASK = 16


@dataclasses.dataclass(frozen=True)
class CriticalityTask:
    """A few scenarios to rate (and whether to keep their per-step criticality)."""

    scenario_ids: tuple
    per_step: bool = False


def rate_scenarios(index: ScenarioIndex, task: CriticalityTask) -> list[dict]:
    """The heuristic criticality of each scenario of a task (`scene_criticality`, plus `steps` if asked); a
    scene rated by an earlier run (`analysis.criticality_cache`) is not rated again unless `steps` are asked."""
    out, computed = [], []
    for sid in task.scenario_ids:
        record = index.load_record(sid)
        key = criticality_cache.record_key(sid, record)
        known = None if task.per_step else criticality_cache.cached(key)
        if known is not None:
            out.append({"scenario_id": sid, **known})
            continue
        features = criticality_features(record_arrays(record, index.source(sid)))
        scene = scene_criticality(features)
        computed.append((key, scene))
        row = {"scenario_id": sid, **scene}
        if task.per_step:
            row["steps"] = [round(float(v), 6) for v in step_criticality(features)]
        out.append(row)
    criticality_cache.keep(computed)
    return out


def _tasks(ids: list[str], per_step: bool) -> Iterable[CriticalityTask]:
    for start in range(0, len(ids), SCENARIOS_PER_TASK):
        yield CriticalityTask(tuple(ids[start : start + SCENARIOS_PER_TASK]), per_step)


def scenario_set_criticality(
    scenarios: PathLike | Iterable[PathLike] | ScenarioIndex,
    *,
    workers: int = 1,
    engine: str = "local",
    ray_address: str | None = None,
    per_step: bool = False,
    progress: Callable[[int, int], None] | None = None,
    executor: Executor | None = None,
) -> dict:
    """Every scenario's criticality against the set, most critical first.

    Args:
      scenarios: TFRecord files, folders or globs of `Scenario`s (or their `ScenarioIndex`).
      workers, engine, ray_address: as for `score_submission`.
      per_step: keep each scenario's per-step criticality (`steps`, 91 values).
      executor: an executor to reuse (`runtime.executors`) instead of making one from the above.
    Returns:
      {"num_scenarios": N, "long_tail_threshold": the top decile's lowest score,
      "histogram": the set's `BehaviourHistogram`, "scenarios": [{"scenario_id", "rank" (1 = most
      critical), "long_tail": bool, "score", "components", "raw", "peak_step"[, "steps"]}, ...]}.
    """
    index = scenarios if isinstance(scenarios, ScenarioIndex) else ScenarioIndex(scenarios)
    executor = executor or make_executor(engine, workers=workers, ray_address=ray_address)
    rows: list[dict] = []
    for done in executor.imap(rate_scenarios, _tasks(index.ids(), per_step), index):
        rows.extend(done)
        if progress is not None:
            progress(len(rows), len(index))
    histogram = set_histogram(rows)
    rated = []
    for row in rows:
        steps = row.pop("steps", None)
        rated.append(
            {
                "scenario_id": row["scenario_id"],
                **with_rarity(row, histogram),
                **({"steps": steps} if steps is not None else {}),
            }
        )
    rated.sort(key=lambda r: (-r["score"], r["scenario_id"]))
    threshold = float(np.quantile([r["score"] for r in rated], LONG_TAIL_QUANTILE)) if rated else math.nan
    for rank, row in enumerate(rated, start=1):
        row["rank"] = rank
        row["long_tail"] = row["score"] >= threshold
    return {"num_scenarios": len(rated), "long_tail_threshold": threshold, "histogram": histogram, "scenarios": rated}


_SELECT = re.compile(r"^top:(?:(?P<fraction>0?\.\d+|1\.0*)|(?P<count>[1-9]\d*))$")


def parse_selection(rule: str) -> tuple[str, float]:
    """`top:0.1` (the most critical tenth) or `top:N` (the N most critical) -> ("fraction"|"count", value)."""
    match = _SELECT.match(rule.strip())
    if not match:
        raise ValueError(
            f"--select {rule!r}: expected top:FRACTION (0 < FRACTION <= 1, e.g. top:0.1) or top:N (e.g. top:100)"
        )
    if match["fraction"] is not None:
        return "fraction", float(match["fraction"])
    return "count", int(match["count"])


def select_scenarios(ranked: list[dict], rule: str) -> list[str]:
    """The scenario ids a `top:` rule keeps from a ranking (most critical first); at least one."""
    kind, value = parse_selection(rule)
    keep = max(1, math.ceil(value * len(ranked))) if kind == "fraction" else int(value)
    return [row["scenario_id"] for row in ranked[:keep]]


__all__ = ["scenario_set_criticality", "select_scenarios", "parse_selection", "rate_scenarios", "CriticalityTask"]
