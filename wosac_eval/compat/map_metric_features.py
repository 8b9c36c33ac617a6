"""`waymo_open_dataset.wdl_limited.sim_agents_metrics.map_metric_features`, without TensorFlow.

    road_edges = [f.road_edge.polyline for f in scenario.map_features if f.HasField("road_edge")]
    distances = map_metric_features.compute_distance_to_road_edge(
        center_x=x, center_y=y, center_z=z, length=length, width=width, height=height, heading=heading,
        valid=valid, evaluated_object_mask=mask, road_edge_polylines=road_edges)
    offroad = distances > map_metric_features.OFFROAD_DISTANCE_THRESHOLD

The distance is the library's own road-edge kernel (`features.road_edge`, the one the metrics use, with
its compiled search): float32, bit for bit the official values. Polylines are lists of map points
(`MapPoint`s) as officially, or arrays `(num_points, 3)`. Arrays `(num_objects, num_steps)` as
officially, or with leading axes `(..., num_objects, num_steps)` (each computed as one official call);
anything implementing `__array__` or `__dlpack__`. Results: numpy arrays answering `.numpy()`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from wosac_eval.compat import _objects
from wosac_eval.compat._arrays import ArrayIn, compat_array
from wosac_eval.features import road_edge
from wosac_eval.features.search import PrunedSearch
from wosac_eval.features.spatial import pad_polylines

# The official module's constants.
EXTREMELY_LARGE_DISTANCE = float(road_edge.EXTREMELY_LARGE_DISTANCE)
OFFROAD_DISTANCE_THRESHOLD = road_edge.OFFROAD_DISTANCE_THRESHOLD


def compute_distance_to_road_edge(
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
    road_edge_polylines: Sequence,
) -> np.ndarray:
    """Signed distance from each evaluated box's most off-road bottom corner to the road edge.

    Args:
      center_x, center_y, center_z, length, width, height, heading: float `(..., num_objects, num_steps)`.
      valid: bool `(..., num_objects, num_steps)`.
      evaluated_object_mask: bool `(num_objects,)`, the objects to score.
      road_edge_polylines: the road edges, each a list of map points (or an array `(num_points, 3)`), the
        road on their left.
    Returns:
      float32 `(..., num_evaluated, num_steps)`: positive off the road, -1e10 where the object is invalid.

    Raises:
      ValueError: 'Missing road edges.' without a road edge of two points or more; the official messages
        for unequal shapes and too few axes; a validity or a mask that does not fit the boxes.
    """
    edges = [p for p in _objects.polyline_arrays(road_edge_polylines) if len(p) >= 2]
    if not edges:
        raise ValueError("Missing road edges.")
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
    order = objects.evaluated_first()
    search = PrunedSearch(_objects.road_edge_table(edges), None, None)
    tails = {"heading_tail": _objects.heading_tail(objects, order)}
    found = _objects.context(objects.laid_out(order), len(objects.evaluated), search, tails)
    with np.errstate(invalid="ignore", over="ignore"):
        return objects.result(found["distance_to_road_edge"])


def tensorize_polylines(polylines: Sequence, ids: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Polylines stacked and zero padded, with a validity flag per point.

    Polylines of fewer than two points are left out, with their ids.

    Args:
      polylines: lists of map points (or arrays `(num_points, 3)`).
      ids: an integer id per polyline; None: all 0.
    Returns:
      float32 `(num_polylines, max_points, 4)` (x, y, z, valid: 1 or 0), and int32 `(num_polylines,)`;
      `(0,)` and `(0,)` when no polyline is kept, as officially.

    Raises:
      ValueError: 'Inconsistent number of polylines and ids.'
    """
    polylines = list(polylines)
    ids = [0] * len(polylines) if ids is None else list(ids)
    if len(ids) != len(polylines):
        raise ValueError("Inconsistent number of polylines and ids.")
    kept = [(a, i) for a, i in ((_objects.polyline_array(p), i) for p, i in zip(polylines, ids)) if len(a) >= 2]
    if not kept:
        return compat_array(np.zeros(0, np.float32)), compat_array(np.zeros(0, np.int32))
    points, point_valid = pad_polylines([a for a, _ in kept], max(len(a) for a, _ in kept))
    stacked = np.concatenate([points, point_valid[..., None].astype(np.float32)], axis=-1)
    return compat_array(stacked, np.float32), compat_array([i for _, i in kept], np.int32)
