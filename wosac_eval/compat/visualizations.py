"""`waymo_open_dataset.utils.sim_agents.visualizations`, without TensorFlow: the tutorial's pictures.

    fig, ax = plt.subplots(1, 1, figsize=(10, 10))
    visualizations.add_map(ax, scenario)
    animation = visualizations.get_animated_states(fig, ax, scenario, x, y, yaw, length, width,
                                                   color_idx=np.zeros(x.shape, int))

The same drawing as the official module (road edges as black dashed lines,
road lines the same at half opacity, boxes as half-transparent rectangles
from `WAYMO_COLORS`, played at 10 Hz), on any matplotlib axis. The arrays
may be numpy arrays or anything `np.asarray` reads (e.g. TensorFlow tensors).

This draws what the official module draws, from the `Scenario` message, so a
tutorial's picture looks as it did; `wosac-eval plot`
(`wosac_eval.results.scene_plot`) draws a scene with rollouts and metric
events instead.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from wosac_eval.protos import map_pb2, scenario_pb2

if TYPE_CHECKING:  # the type alone: matplotlib is imported when a function draws
    from matplotlib.axes import Axes

# The official palette (RGB in [0, 1]): blue, green, amber, coral, purple, navy.
WAYMO_COLORS = (
    np.array(
        [[0, 120, 255], [0, 232, 157], [255, 205, 85], [244, 175, 145], [145, 80, 200], [0, 51, 102]], dtype=np.float64
    )
    / 255.0
)


class _Style(TypedDict):
    fmt: str
    alpha: float


_EDGE_STYLE: _Style = {"fmt": "k--", "alpha": 1.0}
_LINE_STYLE: _Style = {"fmt": "k--", "alpha": 0.5}
_BOX_ALPHA = 0.5
_FRAME_MS = 100  # one 10 Hz step per frame: real time


def _plot_polyline(axis: Axes, polyline: Any, fmt: str, alpha: float) -> None:
    if len(polyline):
        axis.plot([p.x for p in polyline], [p.y for p in polyline], fmt, alpha=alpha)


def add_map(axis: Axes, scenario: scenario_pb2.Scenario) -> None:
    """Draws the scenario's road edges and road lines on `axis` (other map features are not drawn)."""
    for feature in scenario.map_features:
        kind = feature.WhichOneof("feature_data")
        if kind == "road_edge":
            add_road_edge(axis, feature.road_edge)
        elif kind == "road_line":
            add_road_line(axis, feature.road_line)


def add_road_edge(axis: Axes, road_edge: map_pb2.RoadEdge) -> None:
    """Draws one road edge: a black dashed line."""
    _plot_polyline(axis, road_edge.polyline, **_EDGE_STYLE)


def add_road_line(axis: Axes, road_line: map_pb2.RoadLine) -> None:
    """Draws one road line: a black dashed line at half opacity."""
    _plot_polyline(axis, road_line.polyline, **_LINE_STYLE)


def get_bbox_patch(x: float, y: float, bbox_yaw: float, length: float, width: float, color_idx: int = 0) -> Any:
    """A `matplotlib.patches.Rectangle` for one box (not yet added to an axis).

    Args:
      x, y: the box centre.
      bbox_yaw: heading in radians (the `Scenario` convention).
      length, width: the box size in metres.
      color_idx: index into `WAYMO_COLORS`; the colour is drawn at half opacity.
    """
    from matplotlib import patches

    x, y, bbox_yaw, length, width = (float(np.asarray(v)) for v in (x, y, bbox_yaw, length, width))
    cos, sin = np.cos(bbox_yaw), np.sin(bbox_yaw)
    # matplotlib places a rectangle by one corner and rotates it about that corner: the corner at
    # (-length/2, -width/2) in the box's own frame, here rotated by the yaw and moved to the centre.
    corner = (x - 0.5 * length * cos + 0.5 * width * sin, y - 0.5 * length * sin - 0.5 * width * cos)
    colour = [*WAYMO_COLORS[int(np.asarray(color_idx))], _BOX_ALPHA]
    return patches.Rectangle(corner, length, width, angle=float(np.rad2deg(bbox_yaw)), color=colour)


def add_all_current_objects(
    axis: Axes, x: np.ndarray, y: np.ndarray, yaw: Any, length: np.ndarray, width: np.ndarray, color_idx: Any
) -> list:
    """Adds one box per object (each argument `(num_objects,)`) to `axis`; returns the added patches."""
    x, y, yaw, length, width, color_idx = (np.asarray(v) for v in (x, y, yaw, length, width, color_idx))
    return [
        axis.add_patch(get_bbox_patch(x[i], y[i], yaw[i], length[i], width[i], color_idx[i])) for i in range(x.shape[0])
    ]


def get_animated_states(
    fig: Any,
    axis: Axes,
    scenario: scenario_pb2.Scenario,
    x: np.ndarray,
    y: np.ndarray,
    yaw: Any,
    length: np.ndarray,
    width: np.ndarray,
    color_idx: Any = None,
) -> Any:
    """A `matplotlib.animation.FuncAnimation` of the boxes over the scenario's map, one frame per step.

    As officially, `fig` is closed first (so a notebook shows the animation, not a second, static
    figure) and the map is drawn on `axis`; every frame replaces the boxes on `axis`.

    Args:
      fig, axis: the figure and the axis to draw on.
      scenario: the scenario whose map is drawn.
      x, y, yaw, length, width: `(num_objects, num_steps)`.
      color_idx: `(num_objects, num_steps)` indices into `WAYMO_COLORS` (None: the first colour).
    """
    import matplotlib.pyplot as plt
    from matplotlib import animation

    x, y, yaw, length, width = (np.asarray(v) for v in (x, y, yaw, length, width))
    color_idx = np.zeros(x.shape, dtype=np.int32) if color_idx is None else np.asarray(color_idx)
    plt.close(fig)
    add_map(axis, scenario)

    def draw_step(t: int) -> list:
        for patch in list(axis.patches):
            patch.remove()
        return add_all_current_objects(axis, x[:, t], y[:, t], yaw[:, t], length[:, t], width[:, t], color_idx[:, t])

    return animation.FuncAnimation(fig, draw_step, frames=x.shape[1], interval=_FRAME_MS, blit=True)
