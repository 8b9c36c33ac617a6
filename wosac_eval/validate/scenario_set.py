"""The scenario set's side of a validation: the sim agent ids of every scenario, and nothing more.

Memory stays bounded: from the scenario set only the sim agent ids of each
scenario are kept (a few hundred bytes per scenario), read from each record's
tracks without a whole parse.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from wosac_eval.arrays.scenario import record_sim_agent_ids
from wosac_eval.parse.errors import ParseError
from wosac_eval.parse.scenarios import ScenarioIndex, ScenarioSource, expand_scenario_paths, scenario_id_of
from wosac_eval.parse.tfrecord import iter_records, read_record_at
from wosac_eval.runtime.executors import Executor, LocalExecutor

PathLike = str | os.PathLike


class ScenarioSetError(ValueError):
    """The scenario set itself cannot be read: the submission cannot be judged (a usage error)."""


def _record_sim_agents(record: bytes, source: ScenarioSource) -> np.ndarray:
    """Sorted sim agent ids of a serialized scenario, read from its tracks alone: a whole parse of each
    scenario cost the validation about a third of its time (a real WOMD scene: 2-6 ms)."""
    return np.unique(record_sim_agent_ids(record, source))


def _sim_agents_of(_shared: Any, item: tuple[str, list[int]]) -> list[np.ndarray]:
    """Sorted sim agent ids of the scenarios at these offsets of one scenario file (a worker task)."""
    path, offsets = item
    return [_record_sim_agents(read_record_at(path, offset), ScenarioSource(Path(path), offset)) for offset in offsets]


def load_sim_agents(
    scenarios: ScenarioIndex | PathLike | Iterable[PathLike],
    progress: Callable[[int], Any] | None = None,
    executor: Executor | None = None,
) -> dict[str, np.ndarray]:
    """scenario_id -> sorted sim agent ids, shape `(num_objects,)`, in scenario-set order.

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
