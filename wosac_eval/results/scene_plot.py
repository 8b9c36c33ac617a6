"""Pictures of a scenario and its rollouts: where a simulator goes wrong, seen.

The map (road edges, lanes, signal states), the logged trajectories, the
simulated ones (a few rollouts as lines, or all of them as a density), the
boxes at a chosen step, and the metric events where they start: collisions,
off-road and red-light runs, as the official features flag them (the same
per-step features the scores come from). As a PNG (one step), a GIF (the
scene playing) or one self-contained HTML page with a step slider.

    view = scene_view(scenario, rollouts, "sim_agents")
    write_scene(view, "scene.png", step=40)
"""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.scenario import ScenarioArrays, scenario_arrays
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.parse.submission_source import find_scenario_rollouts
from wosac_eval.scoring.scenario import scenario_inputs

FORMATS = (".png", ".gif", ".html")
# (feature, label, marker, colour) of each event drawn.
EVENT_KINDS = (
    ("collision_per_step", "collision", "X", "#d1242f"),
    ("offroad_per_step", "off-road", "^", "#e36209"),
    ("traffic_light_violation_per_step", "red-light run", "s", "#8250df"),
)
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


@dataclasses.dataclass(frozen=True)
class SceneEvent:
    """The start of a run of flagged steps of one object in one rollout.

    Attributes:
      kind: "collision", "off-road" or "red-light run".
      rollout, object_id: where.
      step: the logged step index (0..90) the run starts at.
      x, y: the object's simulated centre there.
    """

    kind: str
    rollout: int
    object_id: int
    step: int
    x: float
    y: float


@dataclasses.dataclass(frozen=True)
class SceneView:
    """What a picture of one scenario shows.

    Attributes:
      scenario: the scenario's arrays (map, log).
      rollouts: the simulated rollouts, or None (the log alone).
      challenge: the challenge the rollouts are for.
      events: every event start, in rollout, object, step order.
      evaluated_ids: int64 `(num_evaluated,)`, the objects whose events are flagged.
    """

    scenario: ScenarioArrays
    rollouts: RolloutArrays | None
    challenge: challenges.Challenge
    events: tuple[SceneEvent, ...]
    evaluated_ids: np.ndarray

    @property
    def first_simulated_step(self) -> int:
        """The logged step index of the first simulated value (11 sim agents, 0 scenario gen)."""
        return challenges.spec(self.challenge).first_simulated_step

    def simulated_step(self, step: int) -> int | None:
        """The rollouts' index of a logged step, or None before the simulation starts."""
        k = step - self.first_simulated_step
        return k if self.rollouts is not None and 0 <= k < self.rollouts.num_steps else None

    def event_counts(self) -> dict[str, int]:
        return {label: sum(e.kind == label for e in self.events) for _, label, _, _ in EVENT_KINDS}


def _event_starts(flags: np.ndarray) -> np.ndarray:
    """(sample, object, step) of the first step of every run of True in bool `(samples, objects, steps)`."""
    before = np.concatenate([np.zeros_like(flags[..., :1]), flags[..., :-1]], axis=-1)
    return np.argwhere(flags & ~before)


def scene_view(scenario, rollouts=None, challenge="sim_agents") -> SceneView:
    """The view of a scenario (a `Scenario` or its arrays) and optionally its rollouts (message or arrays).

    Raises:
      ValueError: the rollouts do not fit the scenario (other scenario, steps, objects).
    """
    challenge = challenges.as_challenge(challenge)
    arrays = scenario if isinstance(scenario, ScenarioArrays) else scenario_arrays(scenario)
    if rollouts is None:
        return SceneView(arrays, None, challenge, (), arrays.evaluated_ids(challenge))
    arrays, rollouts = scenario_inputs(arrays, rollouts, challenge)
    _, sim = scenario_features(arrays, rollouts, challenge=challenge)
    first = challenges.spec(challenge).first_simulated_step
    # Each rollout lists its objects in its own order; events come in the evaluated order.
    position = {
        (r, int(oid)): i for r in range(rollouts.num_rollouts) for i, oid in enumerate(rollouts.object_id[r].tolist())
    }
    events = []
    for feature, label, _, _ in EVENT_KINDS:
        for r, e, k in _event_starts(np.asarray(getattr(sim, feature), dtype=bool)).tolist():
            object_id = int(sim.object_id[e])
            i = position[(r, object_id)]
            events.append(
                SceneEvent(label, r, object_id, first + k, float(rollouts.x[r, i, k]), float(rollouts.y[r, i, k]))
            )
    events.sort(key=lambda ev: (ev.rollout, ev.object_id, ev.step))
    return SceneView(arrays, rollouts, challenge, tuple(events), np.asarray(sim.object_id))


# --------------------------------------------------------------------------------------------
# Drawing


def _box_corners(x, y, heading, length, width) -> np.ndarray:
    """Corners `(num_boxes, 4, 2)` of boxes centred at x, y (all `(num_boxes,)`)."""
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
    ):
        from matplotlib.figure import Figure

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
        from matplotlib.collections import LineCollection

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
        from matplotlib.lines import Line2D

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
        from matplotlib.collections import PolyCollection

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

    def _rollout_boxes(self, r: int, k: int, step: int):
        from matplotlib.collections import PolyCollection

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
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(self.figure)
        buffer = io.BytesIO()
        self.figure.savefig(buffer, format="png", dpi=dpi, metadata={"Software": None})
        return buffer.getvalue()

    def frames(self, steps: Sequence[int], dpi: int):
        """The figure at each step as a PIL image: the static layer is drawn once, each step's artists over it."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from PIL import Image

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


# --------------------------------------------------------------------------------------------
# Files


def default_step(view: SceneView) -> int:
    """The last simulated step with an event if any, else the last step: where something is to be seen."""
    return max((e.step for e in view.events), default=challenges.NUM_LOGGED_STEPS - 1)


def animation_steps(every: int) -> list[int]:
    return list(range(0, challenges.NUM_LOGGED_STEPS, every)) + (
        [challenges.NUM_LOGGED_STEPS - 1] if (challenges.NUM_LOGGED_STEPS - 1) % every else []
    )


def scene_png(
    view: SceneView,
    *,
    step: int | None = None,
    rollouts: Sequence[int] | None = None,
    density: bool = False,
    dpi: int = 100,
    size=(8.0, 7.0),
) -> bytes:
    """A PNG of the view at one step (default: the last event, else the last step)."""
    painter = ScenePainter(view, rollouts, density, size)
    painter.show_step(default_step(view) if step is None else step)
    return painter.png_bytes(dpi)


def scene_gif(
    view: SceneView, *, rollouts: Sequence[int] | None = None, density: bool = False, every: int = 2, dpi: int = 72
) -> bytes:
    """A GIF playing the scene: one frame every `every` steps, at 10 Hz scene time."""
    frames = list(ScenePainter(view, rollouts, density).frames(animation_steps(every), dpi))
    buffer = io.BytesIO()
    frames[0].save(buffer, format="GIF", save_all=True, append_images=frames[1:], duration=100 * every, loop=0)
    return buffer.getvalue()


_HTML_SCRIPT = """
const frames = JSON.parse(document.getElementById('frames').textContent);
const img = document.getElementById('frame'), slider = document.getElementById('step'),
      label = document.getElementById('step-label'), play = document.getElementById('play');
function show(i) { img.src = 'data:image/png;base64,' + frames[i].png; slider.value = i;
                   label.textContent = 'step ' + frames[i].step; }
slider.max = frames.length - 1;
slider.addEventListener('input', () => show(Number(slider.value)));
let timer = null;
play.addEventListener('click', () => {
  if (timer) { clearInterval(timer); timer = null; play.textContent = 'play'; return; }
  play.textContent = 'pause';
  timer = setInterval(() => show((Number(slider.value) + 1) % frames.length), 200);
});
show(Number(document.body.dataset.start));
"""


def scene_html(
    view: SceneView, *, rollouts: Sequence[int] | None = None, density: bool = False, every: int = 2, dpi: int = 72
) -> str:
    """One self-contained HTML page: the scene at every `every` steps behind a slider, and its events."""
    steps = animation_steps(every)
    frames: list[dict[str, Any]] = []
    for step, image in zip(steps, ScenePainter(view, rollouts, density).frames(steps, dpi)):
        buffer = io.BytesIO()
        # A map is mostly flat colour: a palette makes each frame several times smaller.
        image.quantize(colors=96).save(buffer, format="PNG")
        frames.append({"step": step, "png": base64.b64encode(buffer.getvalue()).decode("ascii")})
    target = default_step(view)
    start = min(range(len(frames)), key=lambda i: abs(frames[i]["step"] - target))
    rows = "".join(
        f"<tr><td>{e.rollout}</td><td>{e.object_id}</td><td>{html.escape(e.kind)}</td><td>{e.step}</td>"
        f"<td>{e.x:.1f}, {e.y:.1f}</td></tr>"
        for e in view.events
    )
    counts = ", ".join(f"{n} {label}" for label, n in view.event_counts().items())
    title = f"{view.scenario.scenario_id} ({view.challenge.value})"
    return (
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
        f"<title>{html.escape(title)}</title><style>body{{font:14px system-ui,sans-serif;margin:1.5em}}"
        "table{border-collapse:collapse}td,th{border-bottom:1px solid #d0d7de;padding:2px 10px;text-align:left}"
        "img{max-width:100%}</style></head>"
        f"<body data-start='{start}'><h1>{html.escape(title)}</h1>"
        f"<p>Events over all {view.rollouts.num_rollouts if view.rollouts is not None else 0} rollouts: "
        f"{html.escape(counts) or 'none'}</p>"
        "<p><button id=play>play</button> <input id=step type=range min=0 value=0 style='width:60%'> "
        "<span id=step-label></span></p><img id=frame alt='scene'>"
        f"<h2>Events ({len(view.events)})</h2><table id=events><tr><th>rollout</th><th>object</th><th>event</th>"
        f"<th>step</th><th>x, y</th></tr>{rows}</table>"
        f"<script type='application/json' id=frames>{json.dumps(frames)}</script>"
        f"<script>{_HTML_SCRIPT}</script></body></html>\n"
    )


def write_scene(
    view: SceneView,
    path: str | Path,
    *,
    step: int | None = None,
    rollouts: Sequence[int] | None = None,
    density: bool = False,
    every: int = 2,
) -> Path:
    """Writes the view as .png (one step), .gif or .html (every `every` steps), by the path's suffix."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".png":
        path.write_bytes(scene_png(view, step=step, rollouts=rollouts, density=density))
    elif suffix == ".gif":
        path.write_bytes(scene_gif(view, rollouts=rollouts, density=density, every=every))
    elif suffix == ".html":
        path.write_text(scene_html(view, rollouts=rollouts, density=density, every=every), encoding="utf-8")
    else:
        raise ValueError(f"{path}: the picture's format comes from its suffix: {', '.join(FORMATS)}")
    return path


def scene_pictures(
    scenarios, submission, scenario_ids: Sequence[str], challenge="sim_agents", dpi: int = 80
) -> list[tuple[str, bytes]]:
    """(scenario_id, PNG) of each scenario the submission holds, in the given order (for reports).

    scenarios: a `ScenarioIndex`, or scenario paths to index.
    submission: an open `SubmissionSource` (read from what its validation recorded, under its
      limits), or a path (read under the default limits).
    Scenarios missing from the scenario set or the submission are left out.
    """
    index = scenarios if isinstance(scenarios, ScenarioIndex) else ScenarioIndex(scenarios)
    wanted = [sid for sid in scenario_ids if sid in index]
    rollouts = find_scenario_rollouts(submission, wanted)
    return [
        (sid, scene_png(scene_view(index.load(sid), rollouts[sid], challenge), dpi=dpi))
        for sid in wanted
        if sid in rollouts
    ]
