"""A simulator's arrays -> rollouts: scored as they are, or serialised as submission messages.

The reverse of `arrays.rollouts.rollout_arrays`. A simulator produces numpy
arrays; `rollouts_from_arrays` checks their shapes and values and makes the
`RolloutArrays` that `score_scenario` takes directly (no protobuf built), and
`rollouts_message` / `rollouts_bytes` turn them into the `ScenarioRollouts` a
submission holds. The bytes are written straight from the arrays (packed
float32 blocks, the canonical field order), byte-identical to what protobuf's
own `SerializeToString` gives for the same message, and hundreds of times
faster than filling a message value by value.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.parse.wire import packed_headers, varint
from wosac_eval.protos import sim_agents_submission_pb2

_TRAJECTORY = sim_agents_submission_pb2.SimulatedTrajectory.DESCRIPTOR.fields_by_name
_COORDINATE_NUMBERS = tuple(_TRAJECTORY[f].number for f in ("center_x", "center_y", "center_z", "heading"))
_SIZE_NUMBERS = tuple(_TRAJECTORY[f].number for f in ("width", "length", "height"))  # wire order
_OBJECT_ID_KEY = varint(_TRAJECTORY["object_id"].number << 3)
_OBJECT_TYPE_KEY = varint(_TRAJECTORY["object_type"].number << 3)
_SCENARIO_ID_KEY = varint((1 << 3) | 2)  # ScenarioRollouts.scenario_id
_JOINT_SCENE_KEY = varint((2 << 3) | 2)  # ScenarioRollouts.joint_scenes
_TRAJECTORY_KEY = varint((1 << 3) | 2)  # JointScene.simulated_trajectories


def _as_float32(name: str, value: Any, shape: tuple[int, ...], scenario_id: str) -> np.ndarray:
    """value broadcast to `shape` as float32, or a ValueError naming the field and both shapes."""
    array = np.asarray(value)
    if array.dtype.kind not in "fiu":
        raise ValueError(f"scenario {scenario_id}: {name} must be numbers, got dtype {array.dtype}")
    try:
        return np.ascontiguousarray(np.broadcast_to(array.astype(np.float32, copy=False), shape))
    except ValueError:
        raise ValueError(
            f"scenario {scenario_id}: {name} has shape {array.shape}, which does not broadcast to "
            f"(num_rollouts, num_objects, num_steps) = {shape}"
        ) from None


def _broadcasts(shape: tuple[int, ...], target: tuple[int, ...]) -> bool:
    try:
        return np.broadcast_shapes(shape, target) == target
    except ValueError:
        return False


def _coordinates_shape(scenario_id: str, coordinates: dict) -> tuple[int, ...]:
    """`(num_rollouts, num_objects, num_steps)`: the shape the four coordinates broadcast to.

    Raises:
      ValueError naming the coordinate(s) whose shape disagrees with the others' (the shape most of
      them share), not merely the first one that does not match x.
    """
    shapes = {name: np.shape(value) for name, value in coordinates.items()}
    try:
        shape = np.broadcast_shapes(*shapes.values())
    except ValueError:
        counts: dict[tuple[int, ...], int] = {}
        for one in shapes.values():
            counts[one] = counts.get(one, 0) + 1
        common = max(counts, key=lambda one: (counts[one], len(one) == 3))  # ties: a 3-d shape
        odd = [name for name, one in shapes.items() if not _broadcasts(one, common)]
        if not odd or len(odd) == len(shapes):  # no shape that most share: list them all
            listed = ", ".join(f"{name} {one}" for name, one in shapes.items())
            raise ValueError(
                f"scenario {scenario_id}: x, y, z and heading do not broadcast to one "
                f"(num_rollouts, num_objects, num_steps) shape: {listed}"
            ) from None
        others = [name for name in shapes if name not in odd]
        raise ValueError(
            f"scenario {scenario_id}: {', '.join(f'{name} has shape {shapes[name]}' for name in odd)}, "
            f"which {'do' if len(odd) > 1 else 'does'} not broadcast to the shape of {', '.join(others)}: {common} "
            "(num_rollouts, num_objects, num_steps)"
        ) from None
    if len(shape) != 3:
        raise ValueError(
            f"scenario {scenario_id}: x must be (num_rollouts, num_objects, num_steps), got shape {shapes['x']}"
        )
    return tuple(shape)


class NonFiniteValueWarning(UserWarning):
    """A NaN or inf position, heading or size: scored as given (NaN spreads into the features, officially too)."""


def _warn_if_not_finite(scenario_id: str, name: str, value: np.ndarray, object_id: np.ndarray) -> None:
    """A `NonFiniteValueWarning` naming the rollout, object and index of the first NaN or inf in `value`."""
    bad = ~np.isfinite(value)
    if bad.any():
        r, i, t = (int(k) for k in np.argwhere(bad)[0])
        warnings.warn(
            f"scenario {scenario_id} rollout {r} object {int(object_id[r, i])}: {name}[{t}] is not finite "
            f"({int(bad.sum())} such value(s) in {name}): scored as given, as the official evaluator "
            "does (NaN spreads into that object's features)",
            NonFiniteValueWarning,
            stacklevel=3,
        )


def rollouts_from_arrays(
    scenario_id: str,
    object_id: ArrayLike,
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    heading: ArrayLike,
    *,
    length: ArrayLike | None = None,
    width: ArrayLike | None = None,
    height: ArrayLike | None = None,
    object_type: ArrayLike | None = None,
) -> RolloutArrays:
    """Rollouts of one scenario from a simulator's arrays, checked.

    Args:
      scenario_id: the scenario simulated.
      object_id: int `(num_objects,)` (the same order in every rollout) or `(num_rollouts, num_objects)`.
      x, y, z, heading: float `(num_rollouts, num_objects, num_steps)`: 80 steps after the current one
        (sim agents) or all 91 steps (scenario gen); anything broadcastable to that shape.
      length, width, height: box sizes, broadcastable to `(num_rollouts, num_objects, num_steps)`
        (e.g. `(num_objects, 1)` for a size constant in time); scenario gen only.
      object_type: int `(num_objects,)` or `(num_rollouts, num_objects)` (`Track.ObjectType`); scenario gen only.
    Returns:
      `RolloutArrays` (float32), for `score_scenario` or `rollouts_message`.
    Raises:
      ValueError naming the scenario, rollout, object and field of the first shape or value at fault (repeated ids, a
      box size without the others). Sizes <= 0, NaN and inf are scored as given, as officially (NaN and inf warn).
    """
    scenario_id = str(scenario_id)
    shape = _coordinates_shape(scenario_id, {"x": x, "y": y, "z": z, "heading": heading})
    coordinates = {
        name: _as_float32(name, value, shape, scenario_id)
        for name, value in (("x", x), ("y", y), ("z", z), ("heading", heading))
    }
    ids = np.asarray(object_id)
    if ids.dtype.kind not in "iu":
        raise ValueError(f"scenario {scenario_id}: object_id must be integers, got dtype {ids.dtype}")
    try:
        ids = np.ascontiguousarray(np.broadcast_to(ids.astype(np.int64), shape[:2]))
    except ValueError:
        raise ValueError(
            f"scenario {scenario_id}: object_id has shape {np.shape(object_id)}, expected ({shape[1]},) or {shape[:2]}"
        ) from None
    for r, row in enumerate(ids):
        unique, counts = np.unique(row, return_counts=True)
        if (counts > 1).any():
            raise ValueError(
                f"scenario {scenario_id} rollout {r}: object {int(unique[counts > 1][0])} appears "
                f"{int(counts.max())} times in object_id"
            )
    for name, value in coordinates.items():
        _warn_if_not_finite(scenario_id, name, value, ids)
    sizes = {"length": length, "width": width, "height": height}
    given = [name for name, value in sizes.items() if value is not None]
    if given and (len(given) < 3 or object_type is None):
        missing = [name for name, value in {**sizes, "object_type": object_type}.items() if value is None]
        raise ValueError(
            f"scenario {scenario_id}: {', '.join(given)} given without {', '.join(missing)}: box "
            "sizes and object types come together (scenario gen)"
        )
    if object_type is not None and not given:
        raise ValueError(f"scenario {scenario_id}: object_type given without length, width and height")
    boxes = {}
    if given:
        for name, size in sizes.items():
            boxes[name] = _as_float32(name, size, shape, scenario_id)
            # Zero, negative and non-finite sizes are scored as given, as the official evaluator does
            # (logged boxes are 0 on a track's invalid steps).
            _warn_if_not_finite(scenario_id, name, boxes[name], ids)
        try:
            boxes["object_type"] = np.ascontiguousarray(
                np.broadcast_to(np.asarray(object_type).astype(np.int32), shape[:2])
            )
        except ValueError:
            raise ValueError(
                f"scenario {scenario_id}: object_type has shape {np.asarray(object_type).shape}, expected "
                f"({shape[1]},) or {shape[:2]}"
            ) from None
    return RolloutArrays(scenario_id=scenario_id, object_id=ids, **coordinates, **boxes).validate()


def _packed_float_blocks(values: np.ndarray, field_numbers: tuple[int, ...]) -> np.ndarray:
    """Wire bytes of packed float fields, uint8 `(num_trajectories, num_bytes)`, from float32
    `(num_trajectories, num_fields, num_steps)`."""
    count, fields, steps = values.shape
    headers = packed_headers(steps, field_numbers)
    out = np.empty((count, fields, headers.shape[1] + 4 * steps), dtype=np.uint8)
    out[:, :, : headers.shape[1]] = headers
    out[:, :, headers.shape[1] :] = values.astype("<f4", copy=False).view(np.uint8).reshape(count, fields, 4 * steps)
    return out.reshape(count, -1)


def _int_varint(value: int) -> bytes:
    """An int32/enum field's varint: negative values as their 64-bit two's complement, as protobuf writes them."""
    return varint(value & 0xFFFFFFFFFFFFFFFF)


def _length_delimited(key: bytes, payload: bytes) -> bytes:
    return key + varint(len(payload)) + payload


def rollouts_bytes(rollouts: RolloutArrays) -> bytes:
    """The serialised `ScenarioRollouts` of the arrays (what `rollouts_message(...).SerializeToString()` gives)."""
    num_rollouts, num_objects, _ = rollouts.x.shape
    coordinates = np.stack([rollouts.x, rollouts.y, rollouts.z, rollouts.heading], axis=2)
    blocks = _packed_float_blocks(coordinates.reshape(num_rollouts * num_objects, 4, -1), _COORDINATE_NUMBERS)
    ids = rollouts.object_id.reshape(-1).tolist()
    if rollouts.has_boxes:
        length, width, height, object_type = rollouts.boxes()
        sizes = np.stack([width, length, height], axis=2)
        size_blocks = _packed_float_blocks(sizes.reshape(num_rollouts * num_objects, 3, -1), _SIZE_NUMBERS)
        types = object_type.reshape(-1).tolist()
        trajectories = [
            _length_delimited(
                _TRAJECTORY_KEY,
                b"".join(
                    (
                        blocks[k].tobytes(),
                        _OBJECT_ID_KEY,
                        _int_varint(ids[k]),
                        size_blocks[k].tobytes(),
                        _OBJECT_TYPE_KEY,
                        _int_varint(types[k]),
                    )
                ),
            )
            for k in range(len(ids))
        ]
    else:
        trajectories = [
            _length_delimited(_TRAJECTORY_KEY, blocks[k].tobytes() + _OBJECT_ID_KEY + _int_varint(ids[k]))
            for k in range(len(ids))
        ]
    scenes = [
        _length_delimited(_JOINT_SCENE_KEY, b"".join(trajectories[r * num_objects : (r + 1) * num_objects]))
        for r in range(num_rollouts)
    ]
    return _length_delimited(_SCENARIO_ID_KEY, rollouts.scenario_id.encode("utf-8")) + b"".join(scenes)


def rollouts_message(rollouts: RolloutArrays) -> sim_agents_submission_pb2.ScenarioRollouts:
    """The `ScenarioRollouts` message of the arrays, for a submission shard."""
    return sim_agents_submission_pb2.ScenarioRollouts.FromString(rollouts_bytes(rollouts))


def joint_scene(
    object_id: ArrayLike,
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    heading: ArrayLike,
    *,
    length: ArrayLike | None = None,
    width: ArrayLike | None = None,
    height: ArrayLike | None = None,
    object_type: ArrayLike | None = None,
) -> sim_agents_submission_pb2.JointScene:
    """One rollout as a `JointScene`: coordinates `(num_objects, num_steps)`, ids `(num_objects,)`, checked as in
    `rollouts_from_arrays` (sizes broadcastable to `(num_objects, num_steps)`, types `(num_objects,)`)."""

    def one(value: ArrayLike | None) -> Any:  # Any: an array where given (x, y, z, heading always are)
        return None if value is None else np.asarray(value)[np.newaxis]

    arrays = rollouts_from_arrays(
        "(joint scene)",
        np.asarray(object_id)[np.newaxis],
        one(x),
        one(y),
        one(z),
        one(heading),
        length=one(length),
        width=one(width),
        height=one(height),
        object_type=one(object_type),
    )
    return rollouts_message(arrays).joint_scenes[0]
