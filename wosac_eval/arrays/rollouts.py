"""A `ScenarioRollouts` message as columnar arrays `(num_rollouts, num_agents, 80)`."""
from __future__ import annotations

import dataclasses

import numpy as np

from wosac_eval.parse.wire import COORDINATE_FIELDS, packed_coordinates
from wosac_eval.protos import sim_agents_submission_pb2


@dataclasses.dataclass(frozen=True)
class RolloutArrays:
    """Simulated futures of one scenario, each joint scene in its own agent order.

    The official evaluator derives the object layout of each joint scene from
    the order its trajectories were submitted in, so that order is kept.

    Attributes:
      scenario_id: the scenario these rollouts continue.
      object_id: int64 `(num_rollouts, num_agents)`, agent order of each rollout.
      x, y, z, heading: float32 `(num_rollouts, num_agents, num_steps)`.
    """

    scenario_id: str
    object_id: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    heading: np.ndarray

    @property
    def num_rollouts(self) -> int:
        return int(self.x.shape[0])


def _scene_values_slow(rollouts, r: int, trajectories, num_steps: int) -> np.ndarray:
    values = np.empty((len(trajectories), 4, num_steps), dtype=np.float32)
    for k, field in enumerate(COORDINATE_FIELDS):
        columns = [getattr(t, field) for t in trajectories]
        if any(len(v) != num_steps for v in columns):
            raise ValueError(f"scenario {rollouts.scenario_id} rollout {r}: {field} "
                             f"lengths differ from {num_steps}")
        values[:, k] = np.array(columns, dtype=np.float32).reshape(len(trajectories), num_steps)
    return values


def rollout_arrays(rollouts: sim_agents_submission_pb2.ScenarioRollouts) -> RolloutArrays:
    """Stacks the joint scenes of a `ScenarioRollouts`.

    Every joint scene must have the same number of trajectories, each with the
    same number of steps (validation reports violations in detail first).
    """
    scenes = rollouts.joint_scenes
    if not scenes:
        raise ValueError(f"scenario {rollouts.scenario_id}: no joint scenes")
    num_agents = len(scenes[0].simulated_trajectories)
    num_steps = len(scenes[0].simulated_trajectories[0].center_x) if num_agents else 0
    ids = np.empty((len(scenes), num_agents), dtype=np.int64)
    out = np.empty((len(scenes), num_agents, 4, num_steps), dtype=np.float32)
    for r, scene in enumerate(scenes):
        trajectories = scene.simulated_trajectories
        if len(trajectories) != num_agents:
            raise ValueError(f"scenario {rollouts.scenario_id} rollout {r}: {len(trajectories)} "
                             f"trajectories, rollout 0 has {num_agents}")
        ids[r] = [t.object_id for t in trajectories]
        regular, values = packed_coordinates(trajectories, num_steps)
        # Canonical layout: read from the wire; anything else: field by field.
        out[r] = values if regular.all() else _scene_values_slow(rollouts, r, trajectories, num_steps)
    return RolloutArrays(scenario_id=rollouts.scenario_id, object_id=ids,
                         x=out[:, :, 0], y=out[:, :, 1], z=out[:, :, 2], heading=out[:, :, 3])
