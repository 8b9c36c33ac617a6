"""`waymo_open_dataset.wdl_limited.sim_agents_metrics.interaction_features`, without TensorFlow.

    distances = interaction_features.compute_distance_to_nearest_object(
        center_x=x, center_y=y, center_z=z, length=length, width=width, height=height, heading=heading,
        valid=valid, evaluated_object_mask=mask)
    collisions = distances < interaction_features.COLLISION_DISTANCE_THRESHOLD
    ttc = interaction_features.compute_time_to_collision_with_object_in_front(
        center_x=x, center_y=y, length=length, width=width, heading=heading, valid=valid,
        evaluated_object_mask=mask, seconds_per_step=0.1)

Each function runs the library's own kernel (`features.registry`'s nearest-object and time-to-collision
kernels, the ones the metrics use): float32, bit for bit the official values. Arrays `(num_objects,
num_steps)` as officially, or with leading axes `(..., num_objects, num_steps)` (each computed as one
official call); anything implementing `__array__` or `__dlpack__`. Results: numpy arrays `(...,
num_evaluated, num_steps)` answering `.numpy()`.
"""

from __future__ import annotations

import math

import numpy as np

from wosac_eval.compat import _objects
from wosac_eval.compat._arrays import ArrayIn
from wosac_eval.features import interaction
from wosac_eval.features.float32_math import packet_tail

# The official module's constants (Python floats; the kernels compare in float32, as the official ops do).
EXTREMELY_LARGE_DISTANCE = float(interaction.EXTREMELY_LARGE_DISTANCE)
COLLISION_DISTANCE_THRESHOLD = interaction.COLLISION_DISTANCE_THRESHOLD
CORNER_ROUNDING_FACTOR = interaction.CORNER_ROUNDING_FACTOR
MAX_HEADING_DIFF = math.radians(75.0)
MAX_HEADING_DIFF_FOR_SMALL_OVERLAP = math.radians(10.0)
SMALL_OVERLAP_THRESHOLD = 0.5
MAXIMUM_TIME_TO_COLLISION = 5.0


def compute_distance_to_nearest_object(
    *,
    center_x: ArrayIn,
    center_y: ArrayIn,
    center_z: ArrayIn,
    length: ArrayIn,
    width: ArrayIn,
    height: ArrayIn,
    heading: ArrayIn,
    valid: ArrayIn,
    evaluated_object_mask: ArrayIn,
    corner_rounding_factor: float = CORNER_ROUNDING_FACTOR,
) -> np.ndarray:
    """Signed distance from each evaluated object to the nearest other valid object (boxes with rounded corners).

    Args:
      center_x, center_y, center_z, length, width, height, heading: float `(..., num_objects, num_steps)`.
      valid: bool `(..., num_objects, num_steps)`.
      evaluated_object_mask: bool `(num_objects,)`, the objects to score (all objects count as obstacles).
      corner_rounding_factor: 0 (rectangles) to 1 (capsules).
    Returns:
      float32 `(..., num_evaluated, num_steps)`; 1e10 where the object is invalid or alone.

    Raises:
      ValueError: the official messages for unequal shapes and too few axes; a validity or a mask that does
        not fit the boxes; a rounding factor outside [0, 1].
    """
    named = {
        "center_x": center_x,
        "center_y": center_y,
        "center_z": center_z,
        "length": length,
        "width": width,
        "height": height,
        "heading": heading,
    }
    objects = _objects.read_objects(named, valid, evaluated_object_mask)
    order = objects.evaluated_first()  # as the official function reorders them
    tails = {"heading_tail": _objects.heading_tail(objects, order)}
    found = _objects.context(objects.laid_out(order), len(objects.evaluated), _objects.no_search(), tails)
    with np.errstate(invalid="ignore", over="ignore"), interaction.corner_rounding(corner_rounding_factor):
        return objects.result(found["distance_to_nearest_object"])


def compute_time_to_collision_with_object_in_front(
    *,
    center_x: ArrayIn,
    center_y: ArrayIn,
    length: ArrayIn,
    width: ArrayIn,
    heading: ArrayIn,
    valid: ArrayIn,
    evaluated_object_mask: ArrayIn,
    seconds_per_step: float,
) -> np.ndarray:
    """Seconds until each evaluated object reaches the valid object it follows, at constant speeds, capped at
    `MAXIMUM_TIME_TO_COLLISION` (also where it follows nothing).

    Args:
      center_x, center_y, length, width, heading: float `(..., num_objects, num_steps)`.
      valid: bool `(..., num_objects, num_steps)`: which objects can be followed.
      evaluated_object_mask: bool `(num_objects,)`, the objects to score.
      seconds_per_step: the step's duration, for the speeds (0.1 in the challenges).
    Returns:
      float32 `(..., num_evaluated, num_steps)`.

    Raises:
      ValueError: as `compute_distance_to_nearest_object`; fewer than 2 steps (the official message: the
        speeds of such series have 2 steps).
    """
    named = {"center_x": center_x, "center_y": center_y, "length": length, "width": width, "heading": heading}
    objects = _objects.read_objects(named, valid, evaluated_object_mask)
    n, t, e = objects.num_objects, objects.num_steps, len(objects.evaluated)
    if t < 2:  # the official speeds of a shorter series have 2 steps, which the official stack refuses
        raise ValueError(f"Shapes of all inputs must match: values[0].shape = [{n},{t}] != values[5].shape = [{n},2]")
    traj, pair_tail = _followers_and_leaders(objects)
    tails = {"ego_tail": packet_tail((t, e, 1)), "pair_tail": pair_tail}
    found = _objects.context(traj, e, _objects.no_search(), tails, seconds_per_step)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        return objects.result(found["time_to_collision"])


def _followers_and_leaders(objects: _objects.Objects) -> tuple[dict, np.ndarray]:
    """The time-to-collision kernel's layout: the evaluated objects first, then every object that can be followed.

    Officially every evaluated object looks at all objects in the caller's order (ties to the first). The
    kernel takes its evaluated objects first and looks at its whole object axis: where the evaluated objects
    are not the caller's first ones, they come first as copies that cannot be followed (invalid), then all
    objects as given. Returns (the kernels' trajectory dict, the official pair packets for that layout).
    """
    n, t, e = objects.num_objects, objects.num_steps, len(objects.evaluated)
    official_pairs = packet_tail((t, e, n))  # (steps, evaluated, all objects in the caller's order)
    if np.array_equal(objects.evaluated, np.arange(e)):
        return objects.laid_out(np.arange(n)), official_pairs
    order = np.concatenate([objects.evaluated, np.arange(n)])
    valid = np.concatenate([np.zeros_like(objects.valid[:, :e]), objects.valid], axis=1)
    pairs = np.concatenate([official_pairs[:, :, objects.evaluated], official_pairs], axis=-1)
    return objects.laid_out(order, valid), pairs
