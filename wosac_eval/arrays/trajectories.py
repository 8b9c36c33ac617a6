"""Object trajectories as immutable float32 arrays, with their shapes checked.

The official evaluator converts every coordinate to float32 before computing
features, so all positions, headings and box sizes here are float32: the same
rounding is what makes our features bit-identical to the official ones.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

TIME_SERIES = ("x", "y", "z", "heading", "length", "width", "height", "valid")  # the per-step fields


@dataclasses.dataclass(frozen=True)
class ObjectTrajectories:
    """Boxes of objects over time; `...` is any number of leading (sample) axes.

    Attributes:
      x, y, z: box centres, float32 `(..., num_objects, num_steps)`.
      heading: yaw in radians, float32 `(..., num_objects, num_steps)`.
      length, width, height: box sizes, float32 `(..., num_objects, num_steps)`.
      valid: bool `(..., num_objects, num_steps)`.
      object_id: int64 `(..., num_objects)`: one row per sample when samples
        list their objects in different orders.
      object_type: int32 `(..., num_objects)` (`Track.ObjectType` values).
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    heading: np.ndarray
    length: np.ndarray
    width: np.ndarray
    height: np.ndarray
    valid: np.ndarray
    object_id: np.ndarray
    object_type: np.ndarray

    def validate(self) -> ObjectTrajectories:
        """Raises ValueError naming the field whose shape or dtype disagrees; returns self."""
        shape = np.shape(self.x)
        if len(shape) < 2:
            raise ValueError(f"ObjectTrajectories.x must be (..., num_objects, num_steps), got shape {shape}")
        for name in TIME_SERIES:
            value = getattr(self, name)
            if np.shape(value) != shape:
                raise ValueError(f"ObjectTrajectories.{name} has shape {np.shape(value)}, x has {shape}")
            kind = np.dtype(value.dtype).kind if hasattr(value, "dtype") else "?"
            if (name == "valid") != (kind == "b"):
                raise ValueError(f"ObjectTrajectories.{name} has dtype {value.dtype}")
        for name in ("object_id", "object_type"):
            value = np.shape(getattr(self, name))
            if value != shape[:-1][-len(value) :] or not value:
                raise ValueError(
                    f"ObjectTrajectories.{name} has shape {value}, expected (..., {shape[-2]}) matching x {shape}"
                )
        return self

    @property
    def num_objects(self) -> int:
        return int(self.x.shape[-2])

    @property
    def num_steps(self) -> int:
        return int(self.x.shape[-1])

    def take_objects(self, indices: np.ndarray) -> ObjectTrajectories:
        """Selects objects by position (`indices`, int: the new object axis), in the given order."""
        indices = np.asarray(indices, dtype=np.int64)
        fields = {f: np.take(getattr(self, f), indices, axis=-2) for f in TIME_SERIES}
        return ObjectTrajectories(
            **fields,
            object_id=np.take(self.object_id, indices, axis=-1),
            object_type=np.take(self.object_type, indices, axis=-1),
        )

    def take_ids(self, object_ids: ArrayLike) -> ObjectTrajectories:
        """Selects objects by id, in the order of `object_ids`; `object_id` must be `(num_objects,)`."""
        return self.take_objects(index_of_ids(self.object_id, object_ids))

    def take_steps(self, steps: slice) -> ObjectTrajectories:
        """The given steps of every object."""
        return dataclasses.replace(self, **{f: getattr(self, f)[..., steps] for f in TIME_SERIES})


def stack_samples(parts: Sequence[ObjectTrajectories]) -> ObjectTrajectories:
    """The samples of each part, one after the other (same objects and steps)."""
    return ObjectTrajectories(
        **{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(ObjectTrajectories)}
    )


def index_of_ids(ids: np.ndarray, wanted: ArrayLike) -> np.ndarray:
    """Positions in `ids` of each id in `wanted`; raises KeyError naming any that is absent."""
    ids = np.asarray(ids)
    wanted = np.asarray(wanted, dtype=ids.dtype)
    order = np.argsort(ids, kind="stable")
    pos = np.searchsorted(ids, wanted, sorter=order)
    pos = np.clip(pos, 0, len(ids) - 1)
    found = order[pos]
    missing = ids[found] != wanted if len(ids) else np.ones(len(wanted), bool)
    if np.any(missing):
        raise KeyError(f"object ids not found: {wanted[missing].tolist()}")
    return found
