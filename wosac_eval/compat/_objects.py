"""What the official per-object feature functions share: their arrays read, checked and laid out for the
library's kernels (`features.registry`), and map polylines read from messages or arrays.

The official functions take `(num_objects, num_steps)` arrays and a mask of the evaluated objects; the
kernels take `(num_samples, num_objects, num_steps)` with the evaluated objects first. Any leading axes of the
arrays are flattened into the samples axis and restored on the way out (each sample is computed as the
official function computes one call).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import numpy as np

from wosac_eval.compat._arrays import bool_array, check_stackable, compat_array, float_array
from wosac_eval.features import registry, road_edge, traffic_lights
from wosac_eval.features.float32_math import packet_tail
from wosac_eval.features.metric_features import FeatureLayout
from wosac_eval.features.search import PrunedSearch

_F = np.float32
# The kernels' names of the official arguments.
KERNEL_NAMES = {
    "center_x": "x",
    "center_y": "y",
    "center_z": "z",
    "length": "length",
    "width": "width",
    "height": "height",
    "heading": "heading",
}


@dataclasses.dataclass(frozen=True)
class Objects:
    """The official arguments, read and checked.

    Attributes:
      arrays: float32 `(num_samples, num_objects, num_steps)` by the kernels' names ("x", "y", ...).
      valid: bool `(num_samples, num_objects, num_steps)`.
      evaluated: int64 `(num_evaluated,)`, the evaluated objects' positions in ascending order.
      lead: the leading axes the samples axis stands for.
    """

    arrays: dict
    valid: np.ndarray
    evaluated: np.ndarray
    lead: tuple

    @property
    def num_objects(self) -> int:
        return self.valid.shape[1]

    @property
    def num_steps(self) -> int:
        return self.valid.shape[2]

    def evaluated_first(self) -> np.ndarray:
        """Every object's position, the evaluated ones first (the official reordering), int64 `(num_objects,)`."""
        others = np.setdiff1d(np.arange(self.num_objects), self.evaluated)
        return np.concatenate([self.evaluated, others]).astype(np.int64)

    def laid_out(self, order: np.ndarray, valid: np.ndarray | None = None) -> dict:
        """The kernels' trajectory dict with the objects in `order` (`valid` instead of the objects' own)."""
        traj = {name: a[:, order] for name, a in self.arrays.items()}
        traj["valid"] = self.valid[:, order] if valid is None else valid
        return traj

    def result(self, value: Any) -> Any:
        """A kernel's `(num_samples, num_evaluated, num_steps)` with the leading axes back."""
        return compat_array(np.reshape(value, self.lead + np.shape(value)[1:]))


def read_objects(named: dict, valid: np.ndarray, evaluated_object_mask: Any) -> Objects:
    """The official arguments checked as the official functions check them (their messages where they have
    one), and clearly where they would silently misalign (a validity or a mask of another size).

    Args:
      named: the float arguments by their official names, in the official stacking order.
    """
    names = list(named)
    arrays = [float_array(v, n) for n, v in named.items()]
    if arrays[0].ndim < 2:  # the official functions unpack (objects, steps, box fields)
        raise ValueError(f"not enough values to unpack (expected 3, got {arrays[0].ndim + 1})")
    check_stackable(arrays, names)
    shape = arrays[0].shape
    valid = bool_array(valid, "valid")
    if valid.shape != shape:
        raise ValueError(f"valid has shape {valid.shape}; {names[0]} and the other boxes' arrays have {shape}")
    mask = bool_array(evaluated_object_mask, "evaluated_object_mask")
    if mask.shape != shape[-2:-1]:
        raise ValueError(
            f"evaluated_object_mask has shape {mask.shape}: it needs one entry per object ({shape[-2]} objects)"
        )
    flat = lambda a: a.reshape((-1,) + shape[-2:])  # noqa: E731
    return Objects(
        arrays={KERNEL_NAMES[n]: flat(a) for n, a in zip(names, arrays)},
        valid=flat(valid),
        evaluated=np.flatnonzero(mask),
        lead=shape[:-2],
    )


def heading_tail(objects: Objects, order: np.ndarray) -> np.ndarray:
    """The official sine and cosine's trailing packet over the boxes, `(objects in order, num_steps)`.

    The official corners come from every box in the caller's order (`(num_objects * num_steps,)` at once):
    the packet is that op's, each box keeping its own bit in any order.
    """
    return packet_tail((objects.num_objects, objects.num_steps))[order]


def context(
    traj: dict, num_evaluated: int, search: PrunedSearch, tails: dict, seconds_per_step: float = 0.1
) -> registry.FeatureContext:
    """The library's `FeatureContext` over `traj` (evaluated objects first), every step reported."""
    layout = FeatureLayout(
        num_evaluated=num_evaluated, first_step=0, seconds_per_step=seconds_per_step, displacement=False
    )
    return registry.FeatureContext(traj, layout, search, tails, registry.OFFICIAL_FEATURES)


def no_search() -> PrunedSearch:
    """A search strategy for the kernels that need no map (nearest object, time to collision)."""
    return PrunedSearch(road_edges=None, lanes=None, signals=None)  # type: ignore[arg-type]


def polyline_array(polyline: Any) -> np.ndarray:
    """A polyline as float32 `(num_points, 3)`: map points (`MapPoint`s, or anything with x, y and z) as the
    official code reads them (float64 values rounded to float32), or an array-like `(num_points, 3)`."""
    points = list(polyline)
    if points and all(hasattr(p, "x") for p in points):
        return np.array([[p.x, p.y, p.z] for p in points], dtype=np.float64).astype(_F)
    array = float_array(np.asarray(points) if points else np.zeros((0, 3)), "polyline")
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"a polyline must be map points or an array (num_points, 3), got shape {array.shape}")
    return array


def polyline_arrays(polylines: Any) -> list[np.ndarray]:
    """Every polyline as float32 `(num_points, 3)` (`polyline_array`)."""
    return [polyline_array(p) for p in polylines]


def _key(arrays: list[np.ndarray]) -> tuple[bytes, tuple]:
    """The polylines' points and lengths, hashable: the same map gives the same key."""
    flat = np.concatenate(arrays) if arrays else np.zeros((0, 3), _F)
    return np.ascontiguousarray(flat, _F).tobytes(), tuple(len(a) for a in arrays)


def _split(points: bytes, lengths: tuple) -> list[np.ndarray]:
    flat = np.frombuffer(points, _F).reshape(-1, 3)
    return np.split(flat, np.cumsum(lengths)[:-1]) if lengths else []


def road_edge_table(edges: list[np.ndarray]) -> road_edge.SegmentTable:
    """The library's segment table of road edges, kept for the last few maps: a logger calls the official
    functions every step with the same polylines, whose table (the search's bucket grid) costs more than the call."""
    return _road_edge_table(*_key(edges))


@functools.lru_cache(maxsize=4)
def _road_edge_table(points: bytes, lengths: tuple) -> road_edge.SegmentTable:
    return road_edge.build_segment_table(_split(points, lengths))


def lane_table(lanes: list[np.ndarray], lane_ids: Any) -> traffic_lights.LaneTable | None:
    """The library's lane table (None when no lane has two points), kept for the last few maps as `road_edge_table`."""
    points, lengths = _key(lanes)
    return _lane_table(points, lengths, tuple(int(i) for i in lane_ids))


@functools.lru_cache(maxsize=4)
def _lane_table(points: bytes, lengths: tuple, lane_ids: tuple) -> traffic_lights.LaneTable | None:
    return traffic_lights.build_lane_table(_split(points, lengths), list(lane_ids))
