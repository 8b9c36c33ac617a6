"""Baseline submissions for a scenario set: run a policy on every scenario, write the shards."""

from __future__ import annotations

import concurrent.futures as futures
import os
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.messages import rollouts_bytes, rollouts_from_arrays
from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.submission_writer import SubmissionMetadata, SubmissionWriter
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import scenario_pb2
from wosac_eval.runtime.processes import worker_pool
from wosac_eval.sim import policies

PathLike = str | os.PathLike

DESCRIPTIONS = {
    "constant_velocity": "Constant velocity: every agent keeps its current velocity and heading.",
    "log_replay_noise": (
        "Logged future plus smooth noise growing to ~0.5 m (uses the future: a reference, not a method)."
    ),
    "idm": "Lane following with an intelligent-driver-model car-following law that stops at red lights.",
}


def policy_rollouts(scenario, policy: str, seed: int = 0, challenge: str = "sim_agents") -> RolloutArrays:
    """A policy's 32 rollouts of a scenario (all 91 steps with boxes and types for scenario gen)."""
    if challenges.spec(challenge).submits_boxes:
        ids, traj, boxes, types = policies.generate_scenario(scenario, policy, seed)
        sizes = {"length": boxes[..., 0], "width": boxes[..., 1], "height": boxes[..., 2], "object_type": types}
    else:
        ids, traj = policies.simulate_scenario(scenario, policy, seed)
        sizes = {}
    # trajectories: (num_rollouts, num_objects, num_steps, [x, y, z, heading])
    return rollouts_from_arrays(scenario.scenario_id, ids, *np.moveaxis(traj, -1, 0), **sizes)


def _simulate(args: tuple[bytes, str, int, str]) -> bytes:
    data, policy, seed, challenge = args
    return rollouts_bytes(policy_rollouts(scenario_pb2.Scenario.FromString(data), policy, seed, challenge))


def _map_bounded(tasks: Iterator, workers: int) -> Iterator[bytes]:
    """`_simulate` over tasks in order; in worker processes with a bounded number in flight,
    so that memory does not grow with the size of the scenario set."""
    if workers <= 1:
        for task in tasks:
            yield _simulate(task)
        return
    with worker_pool(workers) as pool:
        pending: list[futures.Future] = []
        for task in tasks:
            pending.append(pool.submit(_simulate, task))
            if len(pending) >= 2 * workers:
                yield pending.pop(0).result()
        for future in pending:
            yield future.result()


def make_submission(
    scenario_paths: PathLike | Iterable[PathLike],
    policy: str,
    output: PathLike,
    *,
    seed: int = 0,
    num_shards: int = 4,
    workers: int = 1,
    metadata: SubmissionMetadata | None = None,
    progress: Callable[[int], None] | None = None,
    challenge: str = "sim_agents",
) -> Path:
    """Simulates `policy` on every scenario and writes an official-layout submission to `output`.

    `challenge="scenario_gen"` writes all 91 steps with box sizes and object
    types (`policies.generate_scenario`). Streams: scenarios are read,
    simulated and appended to the shards one at a time.
    """
    challenge = challenges.as_challenge(challenge).value
    if policy not in policies.POLICIES:
        raise ValueError(f"unknown policy {policy!r}; choose from {', '.join(policies.POLICIES)}")
    metadata = metadata or SubmissionMetadata(
        unique_method_name=policy.replace("_", "-"), description=DESCRIPTIONS[policy]
    )
    tasks = ((s.scenario.SerializeToString(), policy, seed, challenge) for s in iter_scenarios(scenario_paths))
    try:
        with SubmissionWriter(metadata, output, num_shards) as writer:
            for data in _map_bounded(tasks, workers):
                writer.add(data)
                if progress:
                    progress(1)
    except ValueError as error:
        if "no scenario rollouts" in str(error):
            raise ValueError(f"no scenarios found in {scenario_paths}") from None
        raise
    return writer.path
