"""A scene drawn with matplotlib: the map (road edges, lanes, signal states), the logged trajectories,
the simulated ones (a few rollouts as lines, or all of them as a density), the boxes at a chosen step
and the metric events where they start. The static layer is drawn once; each step's artists over it.
"""

from __future__ import annotations

import io
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from PIL import Image

from wosac_eval import challenges
from wosac_eval.results.scene_events import EVENT_KINDS, SceneView

_SIGNAL_COLOURS = {
    1: "#d1242f",
    4: "#d1242f",
    7: "#d1242f",
    2: "#d4a72c",
    5: "#d4a72c",
    8: "#d4a72c",
    3: "#1a7f37",
    6: "#1a7f37",
}  # stop / caution / go (arrow, plain, flashing); else grey
_PALETTE = (
    "#0969da",
    "#1a7f37",
    "#bf3989",
    "#9a6700",
    "#8250df",
    "#0a3069",
    "#116329",
    "#953800",
    "#cf222e",
    "#57606a",
)


def _box_corners(
    x: np.ndarray, y: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray
) -> np.ndarray:
    """Corners `(num_objects, 4, 2)` of boxes centred at x, y (all `(num_objects,)`)."""
    c, s = np.cos(heading), np.sin(heading)
    half = np.stack([length, width], axis=-1)[:, None, :] / 2 * np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]])
    return np.stack(
        [
            x[:, None] + half[..., 0] * c[:, None] - half[..., 1] * s[:, None],
            y[:, None] + half[..., 0] * s[:, None] + half[..., 1] * c[:, None],
        ],
        axis=-1,
    )


class ScenePainter:
    """Draws a view on one matplotlib figure: a static layer once, then the boxes of any step.

    Args:
      view: what to draw.
      rollouts: indices of the rollouts drawn as lines (default the first three); ignored with density.
      density: draw every rollout's positions as a density instead of lines.
      size: figure size in inches.
    """

    def __init__(
        self,
        view: SceneView,
        rollouts: Sequence[int] | None = None,
        density: bool = False,
        size: tuple[float, float] = (8.0, 7.0),
    ) -> None:
        self.view = view
        total = view.rollouts.num_rollouts if view.rollouts is not None else 0
        chosen = list(range(min(3, total))) if rollouts is None or not total else list(rollouts)
        bad = [r for r in chosen if not 0 <= r < total]
        if bad:
            raise ValueError(f"rollout {bad[0]} does not exist: the submission has {total} rollouts (0..{total - 1})")
        self.rollouts = list(range(total)) if density else chosen
        self.density = density
        x0, x1, y0, y1 = self._extent()
        # The map keeps its aspect: the figure's height follows the scene's (within reason).
        width = size[0]
        map_height = min(max(0.64 * width * (y1 - y0) / max(x1 - x0, 1e-6), 3.5), 9.0)
        bottom, top = 0.55, 0.35  # inches for the tick labels and axis label, and for the title
        height = map_height + bottom + top
        self.figure = Figure(figsize=(width, height))
        self.ax = self.figure.add_axes((0.09, bottom / height, 0.63, map_height / height))
        self.colour = {int(oid): _PALETTE[k % len(_PALETTE)] for k, oid in enumerate(view.evaluated_ids.tolist())}
        self._dynamic: list = []
        self._draw_static()

    # -- static layer --------------------------------------------------------------------
    def _extent(self) -> tuple[float, float, float, float]:
        log = self.view.scenario.log.take_ids(self.view.scenario.sim_agent_ids)
        xs, ys = [log.x[log.valid]], [log.y[log.valid]]
        if self.view.rollouts is not None:
            sim = self.view.rollouts
            # Percentiles, not extremes: one rollout flying away must not shrink the scene to a dot.
            xs.append(np.percentile(sim.x, [1, 99]))
            ys.append(np.percentile(sim.y, [1, 99]))
        x, y = np.concatenate(xs), np.concatenate(ys)
        if x.size == 0:
            return -50.0, 50.0, -50.0, 50.0
        pad = 15.0
        return float(x.min() - pad), float(x.max() + pad), float(y.min() - pad), float(y.max() + pad)

    def _draw_map(self) -> None:
        arrays = self.view.scenario
        lanes = [lane[:, :2] for lane in arrays.lanes if len(lane) > 1]
        edges = [edge[:, :2] for edge in arrays.road_edges if len(edge) > 1]
        self.ax.add_collection(LineCollection(lanes, colors="#d0d7de", linewidths=0.6, zorder=1))
        self.ax.add_collection(LineCollection(edges, colors="#24292f", linewidths=1.0, zorder=2))

    def _draw_log(self) -> None:
        log = self.view.scenario.log.take_ids(self.view.scenario.sim_agent_ids)
        for k, object_id in enumerate(log.object_id.tolist()):
            valid = log.valid[k]
            colour = self.colour.get(object_id, "#8c959f")
            self.ax.plot(
                np.where(valid, log.x[k], np.nan),
                np.where(valid, log.y[k], np.nan),
                ls=(0, (3, 2)),
                lw=0.9,
                color=colour,
                alpha=0.7,
                zorder=3,
            )

    def _draw_rollouts(self) -> None:
        sim = self.view.rollouts
        if sim is None:
            return
        if self.density:
            x0, x1, y0, y1 = self._extent()
            counts, xe, ye = np.histogram2d(sim.x.ravel(), sim.y.ravel(), bins=160, range=((x0, x1), (y0, y1)))
            shown = np.ma.masked_equal(np.log1p(counts.T), 0)
            self.ax.imshow(
                shown,
                origin="lower",
                extent=(x0, x1, y0, y1),
                cmap="Blues",
                alpha=0.85,
                interpolation="nearest",
                zorder=4,
                aspect="auto",
            )
            return
        styles = ("-", "--", ":", "-.")
        for n, r in enumerate(self.rollouts):
            for i, object_id in enumerate(sim.object_id[r].tolist()):
                self.ax.plot(
                    sim.x[r, i],
                    sim.y[r, i],
                    ls=styles[n % len(styles)],
                    lw=1.2,
                    color=self.colour.get(object_id, "#6e7781"),
                    alpha=0.9 if object_id in self.colour else 0.45,
                    zorder=4,
                )

    def _draw_static(self) -> None:
        ax = self.ax
        ax.set_title(f"scenario {self.view.scenario.scenario_id}", fontsize=9)
        self._draw_map()
        self._draw_log()
        self._draw_rollouts()
        x0, x1, y0, y1 = self._extent()
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal", adjustable="box")
        ax.tick_params(labelsize=7)
        ax.set_xlabel("x (m)", fontsize=8)
        ax.set_ylabel("y (m)", fontsize=8)
        counts = self.view.event_counts()
        handles = [
            Line2D([], [], color="#24292f", lw=1.0, label="road edge"),
            Line2D([], [], color="#57606a", lw=0.9, ls=(0, (3, 2)), label="logged"),
        ]
        if self.view.rollouts is not None:
            what = (
                f"all {self.view.rollouts.num_rollouts} rollouts (density)"
                if self.density
                else f"rollout{'s' if len(self.rollouts) > 1 else ''} {', '.join(map(str, self.rollouts))}"
            )
            handles.append(Line2D([], [], color="#0969da", lw=1.2, label=what))
            for _, label, marker, colour in EVENT_KINDS:
                handles.append(
                    Line2D([], [], ls="", marker=marker, color=colour, markersize=7, label=f"{label} ({counts[label]})")
                )
        self.figure.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.74, 0.95), fontsize=8, frameon=False)
        self.figure.text(0.745, 0.03, self._summary(), fontsize=7, va="bottom", family="monospace")

    def _summary(self) -> str:
        view = self.view
        lines = [
            f"scenario {view.scenario.scenario_id}",
            f"challenge {view.challenge.value}",
            f"{view.scenario.sim_agent_ids.size} sim agents, {view.evaluated_ids.size} evaluated",
        ]
        shown = [e for e in view.events if e.rollout in self.rollouts]
        if shown:
            lines.append("")
            lines.append("first events shown:")
            lines += [f" r{e.rollout} obj {e.object_id}: {e.kind} @ {e.step}" for e in shown[:12]]
            if len(shown) > 12:
                lines.append(f" ... {len(shown) - 12} more")
        return "\n".join(lines)

    # -- one step ----------------------------------------------------------------------------
    def show_step(self, step: int) -> None:
        """Boxes (logged, and of the first drawn rollout), signal states and the events so far, at a step."""
        if not 0 <= step < challenges.NUM_LOGGED_STEPS:
            raise ValueError(f"step {step} is outside the scenario's steps 0..{challenges.NUM_LOGGED_STEPS - 1}")
        for artist in self._dynamic:
            artist.remove()
        self._dynamic = []
        view, ax = self.view, self.ax
        log = view.scenario.log.take_ids(view.scenario.sim_agent_ids)
        valid = log.valid[:, step]
        corners = _box_corners(
            log.x[valid, step],
            log.y[valid, step],
            log.heading[valid, step],
            log.length[valid, step],
            log.width[valid, step],
        )
        outlines = PolyCollection(
            corners,  # type: ignore[arg-type]  # (N, 4, 2) polygons: matplotlib takes them, its stubs ask a Sequence
            facecolors="none",
            edgecolors="#24292f",
            linewidths=0.8,
            zorder=6,
        )
        self._dynamic.append(ax.add_collection(outlines))
        k = view.simulated_step(step)
        if k is not None and self.rollouts:
            self._dynamic.append(ax.add_collection(self._rollout_boxes(self.rollouts[0], k, step)))
        signals = view.scenario.signals
        if signals is not None and step < signals.state.shape[0]:
            states = signals.state[step]
            on = states > 0
            if on.any():
                colours = [_SIGNAL_COLOURS.get(int(s), "#8c959f") for s in states[on]]
                points = signals.stop_point[step][on]
                self._dynamic.append(
                    ax.scatter(
                        points[:, 0], points[:, 1], s=22, c=colours, zorder=7, edgecolors="white", linewidths=0.6
                    )
                )
        for _, label, marker, colour in EVENT_KINDS:
            happened = [e for e in view.events if e.kind == label and e.step <= step and e.rollout in self.rollouts]
            if happened:
                self._dynamic.append(
                    ax.scatter(
                        [e.x for e in happened],
                        [e.y for e in happened],
                        marker=marker,
                        s=60,
                        c=colour,
                        edgecolors="white",
                        linewidths=0.7,
                        zorder=8,
                    )
                )
        seconds = (step - challenges.CURRENT_TIME_INDEX) * challenges.STEP_SECONDS
        label = f"step {step} ({seconds:+.1f} s)" + (
            "" if k is None or not self.rollouts else f", boxes of rollout {self.rollouts[0]}"
        )
        self._dynamic.append(
            ax.text(
                0.01,
                0.99,
                label,
                transform=ax.transAxes,
                va="top",
                fontsize=8,
                zorder=9,
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"},
            )
        )

    def _rollout_boxes(self, r: int, k: int, step: int) -> Any:
        sim, scenario = self.view.rollouts, self.view.scenario
        if sim is None:
            raise ValueError("the view has no rollouts to draw")
        ids = sim.object_id[r]
        if sim.length is not None and sim.width is not None:  # rollouts with boxes (Scenario Generation)
            length, width = sim.length[r, :, k], sim.width[r, :, k]
        else:  # sim agents: the log's size at the current step, as the evaluator takes it
            log = scenario.log.take_ids(ids)
            length = log.length[:, challenges.CURRENT_TIME_INDEX]
            width = log.width[:, challenges.CURRENT_TIME_INDEX]
        corners = _box_corners(sim.x[r, :, k], sim.y[r, :, k], sim.heading[r, :, k], length, width)
        colours = [self.colour.get(int(i), "#8c959f") for i in ids.tolist()]
        return PolyCollection(
            corners,  # type: ignore[arg-type]  # (N, 4, 2) polygons: matplotlib takes them, its stubs ask a Sequence
            facecolors=colours,
            edgecolors="white",
            linewidths=0.5,
            alpha=0.75,
            zorder=6,
        )

    def png_bytes(self, dpi: int = 100) -> bytes:
        FigureCanvasAgg(self.figure)
        buffer = io.BytesIO()
        self.figure.savefig(buffer, format="png", dpi=dpi, metadata={"Software": None})
        return buffer.getvalue()

    def frames(self, steps: Sequence[int], dpi: int) -> Iterator[Image.Image]:
        """The figure at each step as a PIL image: the static layer is drawn once, each step's artists over it."""
        self.show_step(steps[0])
        canvas = FigureCanvasAgg(self.figure)
        self.figure.set_dpi(dpi)
        for artist in self._dynamic:
            artist.set_visible(False)
        canvas.draw()
        background = canvas.copy_from_bbox(self.figure.bbox)
        for step in steps:
            self.show_step(step)
            canvas.restore_region(background)
            for artist in self._dynamic:
                self.ax.draw_artist(artist)
            yield Image.frombuffer("RGBA", canvas.get_width_height(), bytes(canvas.buffer_rgba())).convert("RGB")
