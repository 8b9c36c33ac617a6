"""Where the scenarios of a submission are scored: in this process, in worker processes, or on Ray.

An engine takes the work of one submission (`ScoringJob`) and yields one
result per scenario in submission order, whatever the order in which the
work finishes, so the result document is identical for every engine and
worker count. `local` (the default, no extra dependency) runs
`workers` processes of this host; `ray` (the `ray` extra) fans shards out to
a Ray cluster (`wosac_eval.scoring.ray_engine`).
"""
from __future__ import annotations

import collections
import dataclasses
from collections.abc import Iterable, Iterator

from wosac_eval import challenges
from wosac_eval.allocator import keep_freed_memory
from wosac_eval.metrics.config import SimAgentMetricsConfig
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.processes import worker_pool
from wosac_eval.protos import sim_agents_submission_pb2

ENGINES = ("local", "ray")
RAY_INSTALL_HINT = "pip install 'wosac-eval[ray]'"


@dataclasses.dataclass(frozen=True)
class ScoringSettings:
    """What every worker needs to score a scenario (small and picklable).

    Attributes:
      config: the serialized `SimAgentMetricsConfig`.
      challenge: the challenge's name.
      backend: "numpy" or "jax".
    """

    config: bytes
    challenge: str
    backend: str = "numpy"

    @property
    def metrics_config(self) -> SimAgentMetricsConfig:
        return SimAgentMetricsConfig.FromString(self.config)


# Worker-process state: the settings and the scenario index, set once per process.
_WORKER: dict = {}


def init_worker(settings: ScoringSettings, index: ScenarioIndex) -> None:
    keep_freed_memory()
    _WORKER.update(settings=settings, config=settings.metrics_config, index=index)


def score_task(scenario_id: str, rollouts_bytes: bytes) -> dict:
    """One scenario, in a worker set up by `init_worker`."""
    from wosac_eval.scoring.scenario import score_scenario

    settings = _WORKER["settings"]
    rollouts = sim_agents_submission_pb2.ScenarioRollouts.FromString(rollouts_bytes)
    return score_scenario(_WORKER["index"].load(scenario_id), rollouts, _WORKER["config"],
                          challenge=settings.challenge, backend=settings.backend)


def score_batch(tasks: list[tuple[str, bytes]]) -> list[dict]:
    """Several scenarios in one jax-backend call (their features are batched)."""
    from wosac_eval.scoring.scenario import score_scenarios_jax

    pairs = [(_WORKER["index"].load(sid), sim_agents_submission_pb2.ScenarioRollouts.FromString(data))
             for sid, data in tasks]
    return score_scenarios_jax(pairs, _WORKER["config"], challenge=_WORKER["settings"].challenge)


JAX_BATCH = 8  # scenarios per jax-backend call in a single process


def _batches(tasks: Iterable, size: int) -> Iterator[list]:
    batch: list = []
    for task in tasks:
        batch.append(task)
        if len(batch) == size:
            yield batch
            batch = []
    if batch:
        yield batch


def score_locally(tasks: Iterable[tuple[str, bytes]], settings: ScoringSettings, index: ScenarioIndex,
                  workers: int = 1) -> Iterator[dict]:
    """Scores (scenario_id, rollouts bytes) tasks in order; with workers, a bounded number in flight."""
    if workers <= 1:
        init_worker(settings, index)
        if settings.backend == "jax":
            for batch in _batches(tasks, JAX_BATCH):
                yield from score_batch(batch)
        else:
            for sid, data in tasks:
                yield score_task(sid, data)
        return
    # JAX runs threads once started: its workers are spawned, not forked.
    with worker_pool(workers, force_spawn=settings.backend == "jax", initializer=init_worker,
                     initargs=(settings, index)) as pool:
        pending: collections.deque = collections.deque()
        for task in tasks:
            pending.append(pool.submit(score_task, *task))
            if len(pending) >= 4 * workers:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


def check_engine(name: str) -> str:
    """Validates an engine name and that its dependencies import; returns the name."""
    if name not in ENGINES:
        raise ValueError(f"unknown engine {name!r}: choose one of {', '.join(ENGINES)}")
    if name == "ray":
        from wosac_eval.backends import BackendUnavailableError
        try:
            import ray  # noqa: F401
        except ImportError as error:
            raise BackendUnavailableError(f"the ray engine needs Ray, which is not installed ({error}); "
                                          f"install it with: {RAY_INSTALL_HINT}") from error
    return name
