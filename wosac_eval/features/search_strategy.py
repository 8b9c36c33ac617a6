"""The interface of a search strategy: the four searches for a nearest thing behind the features.

`metric_features.per_step_features` computes every feature once, for numpy and
JAX alike, and hands the searches to a strategy: `search.PrunedSearch` (numpy,
compiled loops over proven bounds), `dense.DenseSearch` (JAX, fixed shapes) and
`backends.host_search.HostSearch` (the pruned search called from a JAX trace).
All return the all-pairs minimum with the same tie rule (lowest index wins), so
their features are bit-identical.

Shapes: `samples` leads every array (the log or the rollouts), then objects
(evaluated objects first) and steps.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol, runtime_checkable


@dataclasses.dataclass(frozen=True, kw_only=True)
class TimeToCollisionInputs:
    """What the time-to-collision search reads: whole trajectories (speeds need neighbouring steps) and
    the steps to report.

    Attributes:
      x, y, length, width, heading, speed: float32 `(num_samples, num_objects, num_steps)`; speed is the
        planar speed (None: `following.time_to_collision` computes it, over `seconds_per_step`).
      valid: bool `(num_samples, num_objects, num_steps)`.
      num_evaluated: the evaluated objects, the first of the object axis.
      steps: the reported steps, a contiguous range of the step axis (default all).
      ego_tail, pair_tail: the official ops' trailing packets, bool `(len(steps), num_evaluated, 1)` and
        `(len(steps), num_evaluated, num_objects)`, from the real (unpadded) shapes (None:
        `following.time_to_collision` computes them from the arrays' shapes; the searches are given them).
      seconds_per_step: the step's duration, for the speeds where `speed` is None.
    """

    x: Any
    y: Any
    length: Any
    width: Any
    heading: Any
    valid: Any
    num_evaluated: int
    speed: Any = None
    steps: slice = dataclasses.field(
        default_factory=lambda: slice(None)
    )  # unhashable before Python 3.12: no plain default
    ego_tail: Any = None
    pair_tail: Any = None
    seconds_per_step: float | None = None


@runtime_checkable
class SearchStrategy(Protocol):
    """The searches of `metric_features.per_step_features` over one scenario's map (numpy or JAX arrays)."""

    def nearest_object(
        self, x: Any, y: Any, length: Any, width: Any, cos_h: Any, sin_h: Any, valid: Any, num_evaluated: int
    ) -> Any:
        """Distance from each evaluated box to the nearest other valid box.

        x, y, length, width, cos_h, sin_h: float32 and valid bool, `(num_samples, num_objects, num_steps)`.
        Returns float32 `(num_samples, num_evaluated, num_steps)` (`interaction.distance_to_nearest_object`).
        """
        ...

    def time_to_collision(self, inputs: TimeToCollisionInputs) -> Any:
        """Seconds until each evaluated object hits the object it follows, capped at 5 s.

        Returns float32 `(num_samples, num_evaluated, len(inputs.steps))` (`following.time_to_collision`).
        """
        ...

    def road_edge_distance(
        self, x: Any, y: Any, bottom: Any, length: Any, width: Any, cos_h: Any, sin_h: Any, valid: Any
    ) -> Any:
        """Signed distance of each box's most off-road bottom corner to the road edge.

        All float32 (valid bool) `(num_samples, num_objects, num_steps)`; returns float32 of that shape, -1e10
        where invalid (`road_edge.box_distance_to_road_edge`).
        """
        ...

    def red_light_violation(self, x: Any, y: Any, valid: Any) -> Any:
        """Whether each object runs a red light at each step: x, y float32 and valid bool
        `(num_samples, num_objects, num_steps)`; returns bool of that shape (`traffic_lights.red_light_violation`)."""
        ...
