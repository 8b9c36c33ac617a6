"""Baseline submissions for a scenario set: run a policy on every scenario, write the shards."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.messages import rollouts_bytes, rollouts_from_arrays
from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.submission_writer import SubmissionMetadata, SubmissionWriter
from wosac_eval.challenges import Challenge, ChallengeLike
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import scenario_pb2
from wosac_eval.runtime.executors import LocalExecutor
from wosac_eval.sim import policies

PathLike = str | os.PathLike

DESCRIPTIONS = {
    "constant_velocity": "Constant velocity: every agent keeps its current velocity and heading.",
    "log_replay_noise": (
        "Logged future plus smooth noise growing to ~0.5 m (uses the future: a reference, not a method)."
    ),
    "idm": "Lane following with an intelligent-driver-model car-following law that stops at red lights.",
}


def policy_rollouts(
    scenario: scenario_pb2.Scenario, policy: str, seed: int = 0, challenge: ChallengeLike = Challenge.SIM_AGENTS
) -> RolloutArrays:
    """A policy's 32 rollouts of a scenario (all 91 steps with boxes and types for scenario gen)."""
    if challenges.spec(challenge).submits_boxes:
        ids, traj, boxes, types = policies.generate_scenario(scenario, policy, seed)
        sizes = {"length": boxes[..., 0], "width": boxes[..., 1], "height": boxes[..., 2], "object_type": types}
    else:
        ids, traj = policies.simulate_scenario(scenario, policy, seed)
        sizes = {}
    # trajectories: (num_rollouts, num_objects, num_steps, [x, y, z, heading])
    return rollouts_from_arrays(scenario.scenario_id, ids, *np.moveaxis(traj, -1, 0), **sizes)


def _simulate(_shared: None, task: tuple[bytes, str, int, str]) -> bytes:
    """One scenario's rollouts, serialized (a worker task: the scenario's bytes, policy, seed, challenge)."""
    data, policy, seed, challenge = task
    return rollouts_bytes(policy_rollouts(scenario_pb2.Scenario.FromString(data), policy, seed, challenge))


def simulate_rollouts(
    scenario_paths: PathLike | Iterable[PathLike],
    policy: str,
    *,
    seed: int = 0,
    challenge: ChallengeLike = Challenge.SIM_AGENTS,
    workers: int = 1,
) -> Iterator[bytes]:
    """Each scenario's serialized `ScenarioRollouts` by `policy`, in the scenarios' order: simulated in
    `workers` processes with a bounded number in flight, so that memory does not grow with the size of
    the scenario set. `challenge="scenario_gen"` gives all 91 steps with box sizes and object types
    (`policies.generate_scenario`)."""
    challenge = challenges.as_challenge(challenge)
    if policy not in policies.POLICIES:
        raise ValueError(f"unknown policy {policy!r}; choose from {', '.join(policies.POLICIES)}")
    tasks = ((s.scenario.SerializeToString(), policy, seed, challenge) for s in iter_scenarios(scenario_paths))
    return LocalExecutor(workers).imap(_simulate, tasks)


def write_submission(
    rollouts: Iterable[bytes], output: PathLike, metadata: SubmissionMetadata, num_shards: int, source: object
) -> Path:
    """Appends serialized `ScenarioRollouts` to the shards of an official-layout submission at `output`
    (streamed: one at a time); `source`, what they were made from, is named when there are none."""
    try:
        with SubmissionWriter(metadata, output, num_shards) as writer:
            for data in rollouts:
                writer.add(data)
    except ValueError as error:
        if "no scenario rollouts" in str(error):
            raise ValueError(f"no scenarios found in {source}") from None
        raise
    return writer.path


def default_metadata(policy: str) -> SubmissionMetadata:
    """A baseline's submission metadata: its name as the method, its one-line description."""
    return SubmissionMetadata(unique_method_name=policy.replace("_", "-"), description=DESCRIPTIONS[policy])


def make_submission(
    scenario_paths: PathLike | Iterable[PathLike],
    policy: str,
    output: PathLike,
    *,
    seed: int = 0,
    num_shards: int = 4,
    workers: int = 1,
    metadata: SubmissionMetadata | None = None,
    challenge: ChallengeLike = Challenge.SIM_AGENTS,
) -> Path:
    """Simulates `policy` on every scenario and writes an official-layout submission to `output`.

    `challenge="scenario_gen"` writes all 91 steps with box sizes and object
    types (`policies.generate_scenario`). Streams: scenarios are read,
    simulated and appended to the shards one at a time (`simulate_rollouts`, `write_submission`:
    a caller that follows the progress takes the two steps itself).
    """
    rollouts = simulate_rollouts(scenario_paths, policy, seed=seed, challenge=challenge, workers=workers)
    return write_submission(rollouts, output, metadata or default_metadata(policy), num_shards, scenario_paths)
