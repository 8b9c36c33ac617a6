"""A `ScenarioRollouts` message as columnar arrays `(num_rollouts, num_agents, num_steps)`."""
from __future__ import annotations

import dataclasses

import numpy as np

from wosac_eval import challenges
from wosac_eval.parse.wire import BOX_FIELDS, COORDINATE_FIELDS, packed_boxes, packed_coordinates, serialized
from wosac_eval.protos import sim_agents_submission_pb2


@dataclasses.dataclass(frozen=True)
class RolloutArrays:
    """Simulated trajectories of one scenario, each joint scene in its own agent order.

    The official evaluator derives the object layout of each joint scene from
    the order its trajectories were submitted in, so that order is kept.

    Attributes:
      scenario_id: the scenario these rollouts continue.
      object_id: int64 `(num_rollouts, num_agents)`, agent order of each rollout.
      x, y, z, heading: float32 `(num_rollouts, num_agents, num_steps)`.
      length, width, height: float32 `(num_rollouts, num_agents, num_steps)`,
        the submitted box sizes (scenario gen), or None (sim agents: the log's).
      object_type: int32 `(num_rollouts, num_agents)`, the submitted types, or None.
    """

    scenario_id: str
    object_id: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    heading: np.ndarray
    length: np.ndarray | None = None
    width: np.ndarray | None = None
    height: np.ndarray | None = None
    object_type: np.ndarray | None = None

    @property
    def num_rollouts(self) -> int:
        return int(self.x.shape[0])

    @property
    def num_steps(self) -> int:
        return int(self.x.shape[-1])

    @property
    def has_boxes(self) -> bool:
        return self.length is not None

    def validate(self) -> "RolloutArrays":
        """Raises ValueError naming the field whose shape or dtype disagrees; returns self."""
        shape = np.shape(self.x)
        if len(shape) != 3:
            raise ValueError(f"RolloutArrays.x must be (num_rollouts, num_agents, num_steps), got {shape}")
        for name in ("y", "z", "heading") + (BOX_FIELDS if self.has_boxes else ()):
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"RolloutArrays.{name} has shape {np.shape(getattr(self, name))}, x has {shape}")
        for name in ("object_id",) + (("object_type",) if self.object_type is not None else ()):
            if np.shape(getattr(self, name)) != shape[:2]:
                raise ValueError(f"RolloutArrays.{name} has shape {np.shape(getattr(self, name))}, "
                                 f"expected {shape[:2]}")
        return self


def _fields_slow(rollouts, r: int, trajectories, fields, num_steps: int, dtype=np.float32) -> np.ndarray:
    """`(num_trajectories, len(fields), num_steps)` read field by field, lengths checked."""
    values = np.empty((len(trajectories), len(fields), num_steps), dtype=dtype)
    for k, field in enumerate(fields):
        columns = [getattr(t, field) for t in trajectories]
        if any(len(v) != num_steps for v in columns):
            official = ("; the official scorer fails on such a scenario too" if field in BOX_FIELDS
                        else "; the official validator refuses it")
            raise ValueError(f"scenario {rollouts.scenario_id} rollout {r}: {field} "
                             f"lengths differ from {num_steps}{official}")
        values[:, k] = np.array(columns, dtype=dtype).reshape(len(trajectories), num_steps)
    return values


def rollout_arrays(rollouts: sim_agents_submission_pb2.ScenarioRollouts,
                   challenge: challenges.Challenge | str = challenges.Challenge.SIM_AGENTS) -> RolloutArrays:
    """Stacks the joint scenes of a `ScenarioRollouts`.

    Every joint scene must have the same number of trajectories, each with the
    same number of steps (validation reports violations in detail first). For
    a challenge whose submissions carry boxes (scenario gen) the per-step sizes
    and the object types are read too.
    """
    scenes = rollouts.joint_scenes
    if not scenes:
        raise ValueError(f"scenario {rollouts.scenario_id}: no joint scenes")
    boxes = challenges.spec(challenge).submits_boxes
    num_agents = len(scenes[0].simulated_trajectories)
    num_steps = len(scenes[0].simulated_trajectories[0].center_x) if num_agents else 0
    ids = np.empty((len(scenes), num_agents), dtype=np.int64)
    out = np.empty((len(scenes), num_agents, 4 + 3 * boxes, num_steps), dtype=np.float32)
    types = np.empty((len(scenes), num_agents), dtype=np.int32)
    for r, scene in enumerate(scenes):
        trajectories = scene.simulated_trajectories
        if len(trajectories) != num_agents:
            raise ValueError(f"scenario {rollouts.scenario_id} rollout {r}: {len(trajectories)} "
                             f"trajectories, rollout 0 has {num_agents}")
        ids[r] = [t.object_id for t in trajectories]
        data = serialized(trajectories)
        # Canonical layout: read from the wire; anything else: field by field.
        regular, values = packed_coordinates(data, num_steps)
        out[r, :, :4] = values if regular.all() else _fields_slow(rollouts, r, trajectories, COORDINATE_FIELDS,
                                                                  num_steps)
        if boxes:
            regular, sizes, kinds = packed_boxes(data, num_steps)
            if regular.all():
                out[r, :, 4:], types[r] = sizes, kinds
            else:
                out[r, :, 4:] = _fields_slow(rollouts, r, trajectories, BOX_FIELDS, num_steps)
                types[r] = [t.object_type for t in trajectories]
    sizes = dict(length=out[:, :, 4], width=out[:, :, 5], height=out[:, :, 6], object_type=types) if boxes else {}
    return RolloutArrays(scenario_id=rollouts.scenario_id, object_id=ids,
                         x=out[:, :, 0], y=out[:, :, 1], z=out[:, :, 2], heading=out[:, :, 3], **sizes)
