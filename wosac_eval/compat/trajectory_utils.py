"""`waymo_open_dataset.utils.trajectory_utils`, without TensorFlow: object boxes over time as numpy arrays.

    trajectories = trajectory_utils.ObjectTrajectories.from_scenario(scenario)
    agents = trajectories.gather_objects_by_id(submission_specs.get_sim_agent_ids(scenario, challenge_type))
    history = agents.slice_time(start_index=0, end_index=11)

The fields are numpy arrays with the official shapes and dtypes (float32
positions, headings and sizes, bool validity, int32 ids and types) where the
official ones are TensorFlow tensors; like those they answer `.numpy()`
(`compat._arrays.CompatArray`). The methods return new objects and never
change the one they are called on. TensorFlow code that used the tensors can
take the arrays as they are (`tf.convert_to_tensor`), or use numpy (e.g.
`np.all(x)` for `tf.reduce_all(x).numpy()`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from wosac_eval.arrays.scenario import track_trajectories
from wosac_eval.arrays.trajectories import TIME_SERIES
from wosac_eval.compat._arrays import compat_array
from wosac_eval.protos import scenario_pb2

_PER_OBJECT = ("object_id", "object_type")


@dataclasses.dataclass(frozen=True)
class ObjectTrajectories:
    """3D boxes of objects over time; `...` is any number of leading axes.

    As officially, the shapes are documented, not enforced.

    Attributes:
      x, y, z: box centres, float32 `(..., num_objects, num_steps)` (the scenario's frame).
      heading: yaw in radians, float32 `(..., num_objects, num_steps)`.
      length, width, height: box sizes, float32 `(..., num_objects, num_steps)`.
      valid: bool `(..., num_objects, num_steps)`.
      object_id: int32 `(..., num_objects)`, the tracks' ids.
      object_type: int32 `(..., num_objects)`, `scenario_pb2.Track.ObjectType` values.
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

    def slice_time(self, start_index: int = 0, end_index: int | None = None) -> ObjectTrajectories:
        """The steps `start_index:end_index` (Python slice semantics; None: to the end) of every time series.

        `object_id` and `object_type` are kept as they are.
        """
        steps = slice(start_index, end_index)
        return ObjectTrajectories(
            **{f: compat_array(getattr(self, f))[..., steps] for f in TIME_SERIES},
            **{f: getattr(self, f) for f in _PER_OBJECT},
        )

    def gather_objects(self, object_indices: Any) -> ObjectTrajectories:
        """The objects at the given positions, in that order (a position may repeat).

        Args:
          object_indices: 1-D integer array-like of positions in the objects axis.

        Raises:
          ValueError: the indices are not 1-D integers.
          IndexError: an index is outside [0, n_objects).
        """
        indices = np.asarray(object_indices)
        if indices.ndim != 1:
            raise ValueError(f"object_indices must be 1-D, got shape {indices.shape}")
        if indices.size == 0:
            indices = indices.astype(np.int64)
        if not np.issubdtype(indices.dtype, np.integer):
            raise ValueError(f"object_indices must be integers, got dtype {indices.dtype}")
        n_objects = np.shape(self.object_id)[-1]
        bad = (indices < 0) | (indices >= n_objects)
        if bad.any():
            raise IndexError(f"object indices {indices[bad].tolist()} are outside [0, {n_objects})")
        return ObjectTrajectories(
            **{f: np.take(compat_array(getattr(self, f)), indices, axis=-2) for f in TIME_SERIES},
            **{f: np.take(compat_array(getattr(self, f)), indices, axis=-1) for f in _PER_OBJECT},
        )

    def gather_objects_by_id(self, object_ids: Any) -> ObjectTrajectories:
        """The objects with the given ids, in the order of `object_ids`.

        Args:
          object_ids: 1-D integer array-like; each id must be in `self.object_id` (which must be 1-D).

        Raises:
          ValueError: an id is absent from `self.object_id`, or `self.object_id` repeats an id that is asked for.
        """
        return self.gather_objects(_positions_of_ids(self.object_id, object_ids))

    @classmethod
    def from_scenario(cls, scenario: scenario_pb2.Scenario) -> ObjectTrajectories:
        """Every track of the scenario, in track order, over all its steps (91 in training and validation
        data, 11 in the test set); every track must have the same number of steps."""
        log = track_trajectories(scenario)  # the library's reading of the tracks (float32, as officially)
        return cls(
            **{f: compat_array(getattr(log, f)) for f in TIME_SERIES},
            object_id=compat_array(log.object_id, np.int32),  # Track.id is an int32 field
            object_type=compat_array(log.object_type, np.int32),
        )


def _positions_of_ids(ids: np.ndarray, wanted: Any) -> np.ndarray:
    """Position in `ids` of each of `wanted`, as the official gather by id finds them."""
    ids, wanted = np.asarray(ids), np.asarray(wanted)
    if ids.ndim != 1 or wanted.ndim != 1:
        raise ValueError(f"object ids must be 1-D (got shapes {ids.shape} and {wanted.shape})")
    matches = wanted[:, None] == ids[None, :]
    count = matches.sum(axis=1)
    if (count < 1).any():
        raise ValueError(f"object ids {wanted[count < 1].tolist()} are not among the trajectories' ids {ids.tolist()}")
    if (count > 1).any():
        raise ValueError(f"object ids {wanted[count > 1].tolist()} appear more than once among the trajectories' ids")
    return matches.argmax(axis=1).astype(np.int32)
