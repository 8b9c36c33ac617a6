"""Baseline submissions for a scenario set: run a policy on every scenario, write the shards."""
from __future__ import annotations

import concurrent.futures as futures
import os
from collections.abc import Callable, Iterable
from pathlib import Path

from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.sim import policies
from wosac_eval.sim.submission_writer import SubmissionMetadata, scenario_rollouts, write_submission

PathLike = str | os.PathLike

DESCRIPTIONS = {
    "constant_velocity": "Constant velocity: every agent keeps its current velocity and heading.",
    "log_replay_noise": "Logged future plus smooth noise growing to ~0.5 m (uses the future: a reference, not a method).",
    "idm": "Lane following with an intelligent-driver-model car-following law that stops at red lights.",
}


def _simulate(args: tuple[bytes, str, int]):
    from wosac_eval.protos import scenario_pb2

    data, policy, seed = args
    scenario = scenario_pb2.Scenario.FromString(data)
    ids, traj = policies.simulate_scenario(scenario, policy, seed)
    return scenario_rollouts(scenario.scenario_id, ids, traj).SerializeToString()


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
) -> Path:
    """Simulates `policy` on every scenario and writes an official-layout submission to `output`."""
    if policy not in policies.POLICIES:
        raise ValueError(f"unknown policy {policy!r}; choose from {', '.join(policies.POLICIES)}")
    from wosac_eval.protos import sim_agents_submission_pb2

    metadata = metadata or SubmissionMetadata(
        unique_method_name=policy.replace("_", "-"), description=DESCRIPTIONS[policy]
    )
    tasks = ((s.scenario.SerializeToString(), policy, seed) for s in iter_scenarios(scenario_paths))
    rollouts = []
    if workers > 1:
        with futures.ProcessPoolExecutor(workers) as pool:
            for data in pool.map(_simulate, tasks):
                rollouts.append(sim_agents_submission_pb2.ScenarioRollouts.FromString(data))
                if progress:
                    progress(1)
    else:
        for task in tasks:
            rollouts.append(sim_agents_submission_pb2.ScenarioRollouts.FromString(_simulate(task)))
            if progress:
                progress(1)
    if not rollouts:
        raise ValueError(f"no scenarios found in {scenario_paths}")
    return write_submission(rollouts, metadata, output, num_shards)
