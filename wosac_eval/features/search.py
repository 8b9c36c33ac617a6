"""The pruned (numpy) search strategy of the feature orchestration.

`metric_features.per_step_features` computes every feature once, for numpy
and JAX alike; the four searches that look for a nearest thing (nearest
object, followed object, nearest road edge, lane of a red-light crossing) are
delegated to a strategy (`search_strategy.SearchStrategy`). This one prunes
candidates by proven bounds in compiled loops (numba: the road edge over a
bucket grid, objects by bounding radii; the lane search with a k-d tree) and
evaluates the exact float32 kernels on the survivors; its dense twin is
`dense.DenseSearch` (JAX, fixed shapes). Both return the all-pairs minimum
with the same tie rule, so their features are bit-identical.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from wosac_eval.arrays.scenario import TrafficSignals
from wosac_eval.features import following, interaction, road_edge, traffic_lights
from wosac_eval.features.search_strategy import TimeToCollisionInputs


@dataclasses.dataclass(frozen=True)
class PrunedSearch:
    """The searches over one scenario's map by compiled loops (numpy arrays; a `SearchStrategy`).

    Attributes:
      road_edges: the road-edge segment table.
      lanes: the surface-street lane table, or None.
      signals: per-step signal states from the first red-light step on, or None.
    """

    road_edges: road_edge.SegmentTable
    lanes: traffic_lights.LaneTable | None
    signals: TrafficSignals | None

    def nearest_object(
        self,
        x: np.ndarray,
        y: np.ndarray,
        length: np.ndarray,
        width: np.ndarray,
        cos_h: np.ndarray,
        sin_h: np.ndarray,
        valid: np.ndarray,
        num_evaluated: int,
    ) -> np.ndarray:
        """`interaction.distance_to_nearest_object`: float32 `(num_samples, num_evaluated, num_steps)`."""
        return interaction.distance_to_nearest_object(x, y, length, width, cos_h, sin_h, valid, num_evaluated)

    def time_to_collision(self, inputs: TimeToCollisionInputs) -> np.ndarray:
        """`following.time_to_collision`: float32 `(num_samples, num_evaluated, len(inputs.steps))`."""
        return following.time_to_collision(inputs)

    def road_edge_distance(
        self,
        x: np.ndarray,
        y: np.ndarray,
        bottom: np.ndarray,
        length: np.ndarray,
        width: np.ndarray,
        cos_h: np.ndarray,
        sin_h: np.ndarray,
        valid: np.ndarray,
    ) -> np.ndarray:
        """`road_edge.box_distance_to_road_edge`: float32 `(num_samples, num_objects, num_steps)`, -1e10 where
        invalid."""
        return road_edge.box_distance_to_road_edge(x, y, bottom, length, width, cos_h, sin_h, valid, self.road_edges)

    def red_light_violation(self, x: np.ndarray, y: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """`traffic_lights.red_light_violation`: bool `(num_samples, num_objects, num_steps)`."""
        return traffic_lights.red_light_violation(x, y, valid, self.lanes, self.signals)


def compile_searches() -> float:
    """Compiles the search loops now (or loads them from numba's cache); returns the seconds it took.

    numba compiles a loop on its first call, once per installation, and caches it on disk; with the
    other rooms' loops, `scoring.warm_up.compile_loops` compiles them ahead of a first scenario.
    """
    start = time.perf_counter()
    f = np.float32
    table = road_edge.build_segment_table([np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0]], f)])
    # Boxes near the edge, on another level, far off the map, and not finite, in 16 samples: enough
    # queries a cell for the cell lists (scoring's case); the centres alone are the scattered case.
    centres = np.array([[2, 1, 0], [5, -1, 9], [4000, 3000, 0], [np.nan, 0, 0]], f)
    x, y, z = np.broadcast_to(centres.T[:, None, :, None], (3, 16, 4, 1))  # each (num_samples, num_objects, num_steps)
    size, turn = np.ones((16, 4, 1), f) * 2, np.ones((16, 4, 1), f) * 0.6  # length = width, cos = sin
    road_edge.box_distance_to_road_edge(x, y, z, size, size, turn, turn, np.ones((16, 4, 1), bool), table)
    road_edge.signed_distance_to_polylines(table, centres)
    x = np.array([[[0, 1, 2], [6, 7, 8]]], f)  # (num_samples, num_objects, num_steps): a follower and its leader
    zeros, ones = np.zeros_like(x), np.ones_like(x)
    with np.errstate(invalid="ignore"):
        interaction.distance_to_nearest_object(x, zeros, ones * 4, ones * 2, ones, zeros, ones > 0, 2)
        boxes = {"x": x, "y": zeros, "length": ones * 4, "width": ones * 2, "heading": zeros, "valid": ones > 0}
        following.time_to_collision(
            TimeToCollisionInputs(**boxes, num_evaluated=2, seconds_per_step=0.1, steps=slice(1, None))
        )
        line = np.zeros((3, 1, 2), f)  # (num_steps, num_signals, 2): a stop line across the road at x = 4
        traffic_lights.compiled_stop_line_crossings(
            x, zeros, ones > 0, line, line + [0, 1], line + [4, 0], np.ones((3, 1), bool)
        )
    return time.perf_counter() - start
