"""Pictures of a scenario and its rollouts: where a simulator goes wrong, seen.

The map (road edges, lanes, signal states), the logged trajectories, the
simulated ones (a few rollouts as lines, or all of them as a density), the
boxes at a chosen step, and the metric events where they start: collisions,
off-road and red-light runs, as the official features flag them (the same
per-step features the scores come from). As a PNG (one step), a GIF (the
scene playing) or one self-contained HTML page with a step slider.

What a picture shows is `scene_events.SceneView` (`scene_view`, importable from here too); the
drawing is `scene_painter.ScenePainter`; this module writes the files.

    view = scene_view(scenario, rollouts, "sim_agents")
    write_scene(view, "scene.png", step=40)
"""

from __future__ import annotations

import base64
import html
import io
import json
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from wosac_eval import challenges
from wosac_eval.parse.scenarios import PathLike, ScenarioIndex
from wosac_eval.parse.submission_source import SubmissionSource, find_scenario_rollouts
from wosac_eval.results.scene_events import EVENT_KINDS, SceneEvent, SceneView, scene_view
from wosac_eval.results.scene_painter import ScenePainter

FORMATS = (".png", ".gif", ".html")
# What pictures are made of, named here as where they are drawn (the service, `plot`, the report).
__all__ = [
    "EVENT_KINDS",
    "FORMATS",
    "SceneEvent",
    "SceneView",
    "animation_steps",
    "default_step",
    "scene_gif",
    "scene_html",
    "scene_pictures",
    "scene_png",
    "scene_view",
    "write_scene",
]


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
    size: tuple[float, float] = (8.0, 7.0),
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
    scenarios: ScenarioIndex | PathLike | Iterable[PathLike],
    submission: PathLike | SubmissionSource,
    scenario_ids: Sequence[str],
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    dpi: int = 80,
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
