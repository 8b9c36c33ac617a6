"""A `ScenarioRollouts` message as columnar arrays `(num_rollouts, num_objects, num_steps)`."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.parse import wire_walks as walks
from wosac_eval.parse.wire import BOX_FIELDS, COORDINATE_FIELDS, TRAJECTORY_FIELD_NUMBERS
from wosac_eval.protos import sim_agents_submission_pb2


@dataclasses.dataclass(frozen=True)
class RolloutArrays:
    """Simulated trajectories of one scenario, each joint scene in its own agent order.

    The official evaluator derives the object layout of each joint scene from
    the order its trajectories were submitted in, so that order is kept.

    Attributes:
      scenario_id: the scenario these rollouts continue.
      object_id: int64 `(num_rollouts, num_objects)`, agent order of each rollout.
      x, y, z, heading: float32 `(num_rollouts, num_objects, num_steps)`.
      length, width, height: float32 `(num_rollouts, num_objects, num_steps)`,
        the submitted box sizes (scenario gen), or None (sim agents: the log's).
      object_type: int32 `(num_rollouts, num_objects)`, the submitted types, or None.
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

    def boxes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """`(length, width, height, object_type)` of rollouts with boxes (Scenario Generation)."""
        if self.length is None or self.width is None or self.height is None or self.object_type is None:
            raise ValueError("these rollouts carry no boxes (length, width, height and object_type)")
        return self.length, self.width, self.height, self.object_type

    def validate(self) -> RolloutArrays:
        """Raises ValueError naming the field whose shape or dtype disagrees; returns self."""
        shape = np.shape(self.x)
        if len(shape) != 3:
            raise ValueError(f"RolloutArrays.x must be (num_rollouts, num_objects, num_steps), got {shape}")
        for name in ("y", "z", "heading") + (BOX_FIELDS if self.has_boxes else ()):
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"RolloutArrays.{name} has shape {np.shape(getattr(self, name))}, x has {shape}")
        for name in ("object_id",) + (("object_type",) if self.object_type is not None else ()):
            if np.shape(getattr(self, name)) != shape[:2]:
                raise ValueError(
                    f"RolloutArrays.{name} has shape {np.shape(getattr(self, name))}, expected {shape[:2]}"
                )
        return self


def _length_error(rollouts: RolloutArrays, r: int, field: str, num_steps: int) -> ValueError:
    official = (
        "; the official scorer fails on such a scenario too"
        if field in BOX_FIELDS
        else "; the official validator refuses it"
    )
    return ValueError(f"scenario {rollouts.scenario_id} rollout {r}: {field} lengths differ from {num_steps}{official}")


def _raise_for_the_first_odd_scene(
    rollouts: sim_agents_submission_pb2.ScenarioRollouts,
    per_scene: np.ndarray,
    scene: np.ndarray,
    wrong_length: Any,
    fields: Any,
    num_steps: int,
) -> None:
    """The error of the first joint scene whose number of trajectories differs from the first one's, or
    in which a field (the first such, in `fields` order) has a length other than `num_steps`."""
    odd = (per_scene != per_scene[0]) | (np.bincount(scene, wrong_length.any(axis=1), len(per_scene)) > 0)
    for r in np.flatnonzero(odd)[:1].tolist():
        if per_scene[r] != per_scene[0]:
            raise ValueError(
                f"scenario {rollouts.scenario_id} rollout {r}: {int(per_scene[r])} "
                f"trajectories, rollout 0 has {int(per_scene[0])}"
            )
        raise _length_error(rollouts, r, fields[int(np.argmax(wrong_length[scene == r].any(axis=0)))], num_steps)


def trajectory_spans(data: np.ndarray) -> tuple[Any, Any, Any, int]:
    """The `SimulatedTrajectory` messages of a serialised `ScenarioRollouts` (joint_scenes is field 2,
    their simulated_trajectories field 1): (starts, ends, joint scene of each) int64 `(num_trajectories,)`,
    and the number of joint scenes."""
    scene_start, scene_end, _ = walks.message_spans(data, *walks.whole(data), 2)
    start, end, scene = walks.message_spans(data, scene_start, scene_end, 1)
    return start, end, scene, len(scene_start)


def trajectory_headers(data: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[Any, Any, Any, Any]:
    """object_id int64, whether it is set (bool), object_type int32 (TYPE_UNSET where unset) and whether it
    is set (bool: `HasField`) of each trajectory span, `(num_trajectories,)`: varint fields 6 (int32) and 10
    (a closed enum)."""
    _, header, present = walks.scalar_fields(
        data,
        start,
        end,
        np.array([6, 10], np.int64),
        np.full(2, walks.WIRE_VARINT),
        np.array([0, _OBJECT_TYPES], np.int64),
    )
    return header[:, 0], present[:, 0], header[:, 1].astype(np.int32), present[:, 1]


def rollout_arrays(
    rollouts: sim_agents_submission_pb2.ScenarioRollouts,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    wire_bytes: bytes | None = None,
) -> RolloutArrays:
    """Stacks the joint scenes of a `ScenarioRollouts` (read from its wire bytes at once).

    Every joint scene must have the same number of trajectories, each with the
    same number of steps (validation reports violations in detail first). For
    a challenge whose submissions carry boxes (scenario gen) the per-step sizes
    and the object types are read too. wire_bytes: the bytes `rollouts` was parsed from, when at
    hand: read instead of serialising the message again (the walks read them as a parse does).
    """
    data = walks.message_bytes(rollouts if wire_bytes is None else wire_bytes)
    start, end, scene, num_scenes = trajectory_spans(data)
    if not num_scenes:
        raise ValueError(f"scenario {rollouts.scenario_id}: no joint scenes")
    boxes = challenges.spec(challenge).submits_boxes
    per_scene = np.bincount(scene, minlength=num_scenes)
    num_agents = int(per_scene[0])
    fields = COORDINATE_FIELDS + (BOX_FIELDS if boxes else ())
    numbers = np.array([TRAJECTORY_FIELD_NUMBERS[f] for f in fields], np.int64)
    num_steps = int(walks.float_fields(data, start[:1], end[:1], numbers[:1], 0)[1][0, 0]) if num_agents else 0
    values, count, _, _ = walks.float_fields(data, start, end, numbers, num_steps)
    _raise_for_the_first_odd_scene(rollouts, per_scene, scene, count != num_steps, fields, num_steps)
    object_id, _, object_type, _ = trajectory_headers(data, start, end)
    out = values.reshape(num_scenes, num_agents, len(fields), num_steps)
    ids = object_id.reshape(num_scenes, num_agents)
    sizes = (
        {
            "length": out[:, :, 4],
            "width": out[:, :, 5],
            "height": out[:, :, 6],
            "object_type": object_type.reshape(num_scenes, num_agents),
        }
        if boxes
        else {}
    )
    return RolloutArrays(
        scenario_id=rollouts.scenario_id,
        object_id=ids,
        x=out[:, :, 0],
        y=out[:, :, 1],
        z=out[:, :, 2],
        heading=out[:, :, 3],
        **sizes,
    )


_OBJECT_TYPES = walks.enum_size(
    sim_agents_submission_pb2.SimulatedTrajectory.DESCRIPTOR.fields_by_name["object_type"].enum_type
)
