"""Object trajectories as immutable float32 arrays.

The official evaluator converts every coordinate to float32 before computing
features, so all positions, headings and box sizes here are float32: the same
rounding is what makes our features bit-identical to the official ones.
"""
from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class ObjectTrajectories:
    """Boxes of objects over time.

    Attributes:
      x, y, z: box centres, float32 `(..., num_objects, num_steps)`.
      heading: yaw in radians, float32 `(..., num_objects, num_steps)`.
      length, width, height: box sizes, float32 `(..., num_objects, num_steps)`.
      valid: bool `(..., num_objects, num_steps)`.
      object_id: int64 `(num_objects,)`.
      object_type: int32 `(num_objects,)` (`Track.ObjectType` values).
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

    @property
    def num_objects(self) -> int:
        return int(self.object_id.shape[0])

    @property
    def num_steps(self) -> int:
        return int(self.x.shape[-1])

    def take_objects(self, indices: np.ndarray) -> "ObjectTrajectories":
        """Selects objects by position, in the given order."""
        indices = np.asarray(indices, dtype=np.int64)
        fields = {f: np.take(getattr(self, f), indices, axis=-2) for f in _TIME_SERIES}
        return ObjectTrajectories(**fields, object_id=self.object_id[indices],
                                  object_type=self.object_type[indices])

    def take_ids(self, object_ids) -> "ObjectTrajectories":
        """Selects objects by id, in the order of `object_ids`."""
        return self.take_objects(index_of_ids(self.object_id, object_ids))


_TIME_SERIES = ("x", "y", "z", "heading", "length", "width", "height", "valid")


def index_of_ids(ids: np.ndarray, wanted) -> np.ndarray:
    """Positions in `ids` of each id in `wanted`; raises if any is absent."""
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
