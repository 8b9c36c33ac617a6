"""One object against its log (`wosac-eval plot --object ID`): where its rollouts go, and its features.

Left, the map with the object's logged trajectory (black, dashed), every rollout of it (blue, thin;
the others' logs in grey) and its events (collision, off-road, red light) where they start. Right,
its metric features over the simulated steps, each rollout (thin) and their median against the log:
speed, acceleration, distance to the nearest object and distance to the road edge (negative: on
the road), the same per-step features its likelihoods come from (`features.metric_features`). Steps
where the log is invalid are left blank in the log's line. Behind them, the likelihood's histogram
(the config's bins of that metric): each bin shaded by the share of the rollouts' values in it, so a
logged line through pale bins is what the metric finds unlikely.
"""

from __future__ import annotations

import dataclasses
import io
import warnings
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from wosac_eval import challenges
from wosac_eval.arrays.object_types import SHORT_NAMES
from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.scenario import ScenarioArrays
from wosac_eval.estimators.likelihoods import histogram_bins, histogram_edges
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2
from wosac_eval.results.scene_events import EVENT_KINDS
from wosac_eval.scoring.scenario import ConfigLike, resolve_config, scenario_inputs

# (feature, title, unit) of each panel.
PANELS = (
    ("linear_speed", "speed", "m/s"),
    ("linear_acceleration", "acceleration", "m/s²"),
    ("distance_to_nearest_object", "distance to nearest object", "m"),
    ("distance_to_road_edge", "distance to road edge", "m"),
)
_LOG, _SIM = "#24292f", "#0969da"


def _shade_bins(axis: Axes, values: np.ndarray, histogram: Any) -> None:
    """Horizontal bands at the histogram's bins, each as dark as the share of `values` that falls in it."""
    edges = histogram_edges(histogram.min_val, histogram.max_val, histogram.num_bins).astype(np.float64)
    finite = values[np.isfinite(values)].astype(np.float32)
    if not finite.size:
        return
    share = np.bincount(histogram_bins(finite, edges.astype(np.float32)), minlength=len(edges) - 1) / finite.size
    for k in np.flatnonzero(share):
        axis.axhspan(edges[k], edges[k + 1], color=_SIM, alpha=0.05 + 0.3 * share[k] / share.max(), lw=0, zorder=0)


@dataclasses.dataclass(frozen=True)
class _ObjectScene:
    """One evaluated object of a scenario, with what its picture draws.

    arrays, rollouts: the scenario's arrays and the rollouts' (`scoring.scenario.scenario_inputs`).
    log, sim: the metric features of the log and of the rollouts (`scenario_features`).
    e: the object's index among the evaluated ones.
    steps: the logged step index of each simulated step, shape `(num_steps,)`.
    """

    object_id: int
    arrays: Any
    rollouts: Any
    log: Any
    sim: Any
    e: int
    steps: np.ndarray

    @property
    def log_valid(self) -> np.ndarray:
        """Whether the log has the object at each simulated step, shape `(num_steps,)`."""
        return np.asarray(self.log.valid)[0, self.e]


def object_png(
    scenario: scenario_pb2.Scenario | ScenarioArrays,
    rollouts: sim_agents_submission_pb2.ScenarioRollouts | RolloutArrays,
    object_id: int,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    dpi: int = 100,
    config: ConfigLike = None,
) -> bytes:
    """The picture of one evaluated object's rollouts against its log (see the module), as PNG bytes.

    `config`: the metrics config whose histogram bins are shaded (default: the challenge's current one).

    Raises:
      ValueError: the rollouts do not fit the scenario, or the object is not evaluated (the message lists
        those that are).
    """
    challenge = challenges.as_challenge(challenge)
    config = resolve_config(config, challenge)
    arrays, sim_arrays = scenario_inputs(scenario, rollouts, challenge)
    log, sim = scenario_features(arrays, sim_arrays, challenge=challenge)
    evaluated = np.asarray(log.object_id).tolist()
    if object_id not in evaluated:
        raise ValueError(
            f"object {object_id} is not evaluated in scenario {arrays.scenario_id}: its features are not "
            f"scored; evaluated objects: {', '.join(map(str, evaluated))}"
        )
    e = evaluated.index(object_id)
    first = challenges.spec(challenge).first_simulated_step
    steps = np.arange(first, first + sim_arrays.num_steps)
    scene = _ObjectScene(object_id, arrays, sim_arrays, log, sim, e, steps)
    kind = SHORT_NAMES.get(int(np.asarray(log.object_type)[0, e]), "other")

    figure = Figure(figsize=(14.0, 7.0))
    FigureCanvasAgg(figure)
    grid = figure.add_gridspec(
        len(PANELS), 2, width_ratios=(1.15, 1.0), hspace=0.45, wspace=0.18, left=0.05, right=0.98, top=0.92, bottom=0.08
    )
    _map_panel(figure.add_subplot(grid[:, 0]), scene)
    figure.suptitle(
        f"scenario {arrays.scenario_id}: object {object_id} ({kind}), its rollouts against its log", fontsize=11
    )
    for p, panel in enumerate(PANELS):
        _feature_panel(figure.add_subplot(grid[p, 1]), scene, panel, getattr(config, panel[0]))
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi, metadata={"Software": None})
    return buffer.getvalue()


def _map_panel(ax: Any, scene: _ObjectScene) -> None:
    """The map: lanes and road edges, the other objects' logs (grey), every rollout of the object (thin),
    its log (dashed) and where each rollout's events start; its legend counts the rollouts with each."""
    arrays, sim_arrays, object_id = scene.arrays, scene.rollouts, scene.object_id
    ax.add_collection(
        LineCollection(
            [lane[:, :2] for lane in arrays.lanes if len(lane) > 1], colors="#d0d7de", linewidths=0.6, zorder=1
        )
    )
    ax.add_collection(
        LineCollection(
            [edge[:, :2] for edge in arrays.road_edges if len(edge) > 1], colors="#24292f", linewidths=1.0, zorder=2
        )
    )
    logged = arrays.log.take_ids(arrays.sim_agent_ids)
    for k, oid in enumerate(logged.object_id.tolist()):
        valid = logged.valid[k]
        xs, ys = np.where(valid, logged.x[k], np.nan), np.where(valid, logged.y[k], np.nan)
        if oid == object_id:
            own = (xs, ys)
        else:
            ax.plot(xs, ys, color="#8c959f", lw=0.7, alpha=0.6, zorder=3)
    rollout_xy = []
    for r in range(sim_arrays.num_rollouts):
        i = sim_arrays.object_id[r].tolist().index(object_id)
        rollout_xy.append((sim_arrays.x[r, i], sim_arrays.y[r, i]))
        ax.plot(sim_arrays.x[r, i], sim_arrays.y[r, i], color=_SIM, lw=0.8, alpha=0.35, zorder=4)
    ax.plot(*own, color=_LOG, lw=1.8, ls=(0, (4, 2)), zorder=5, label="logged")
    counts = _mark_event_starts(ax, scene, rollout_xy)
    xs = np.concatenate([own[0][np.isfinite(own[0])], np.percentile([p[0] for p in rollout_xy], [1, 99])])
    ys = np.concatenate([own[1][np.isfinite(own[1])], np.percentile([p[1] for p in rollout_xy], [1, 99])])
    pad = 20.0
    ax.set_xlim(xs.min() - pad, xs.max() + pad)
    ax.set_ylim(ys.min() - pad, ys.max() + pad)
    ax.set_aspect("equal", adjustable="box")
    ax.tick_params(labelsize=7)
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    handles = [
        Line2D([], [], color=_LOG, lw=1.8, ls=(0, (4, 2)), label="logged"),
        Line2D([], [], color=_SIM, lw=0.8, label=f"{sim_arrays.num_rollouts} rollouts"),
        Line2D([], [], color="#8c959f", lw=0.7, label="other objects (logged)"),
    ]
    handles += [
        Line2D([], [], ls="", marker=m, color=c, label=f"{label} ({counts[label]} rollouts)")
        for _, label, m, c in EVENT_KINDS
    ]
    ax.legend(handles=handles, fontsize=7, loc="upper left", framealpha=0.85)


def _mark_event_starts(ax: Any, scene: _ObjectScene, rollout_xy: list) -> dict[str, int]:
    """Mark where each rollout's first event of each kind is (steps the log has the object); the number of
    rollouts with one, per kind."""
    counts = {}
    for feature, label, marker, colour in EVENT_KINDS:
        flags = np.asarray(getattr(scene.sim, feature))[:, scene.e] & scene.log_valid[None]
        hit = np.flatnonzero(flags.any(axis=-1))
        counts[label] = int(hit.size)
        for r in hit.tolist():
            k = int(flags[r].argmax())
            ax.plot(
                rollout_xy[r][0][k], rollout_xy[r][1][k], ls="", marker=marker, color=colour, markersize=7, zorder=6
            )
    return counts


def _feature_panel(axis: Axes, scene: _ObjectScene, panel: tuple[str, str, str], metric: Any) -> None:
    """One feature over the simulated steps: each rollout (thin), their median, the log (dashed), over the
    shaded bins of its likelihood's histogram (when the metric has one)."""
    feature, title, unit = panel
    values = np.asarray(getattr(scene.sim, feature), dtype=np.float64)[:, scene.e]
    values = np.where(np.isfinite(values), values, np.nan)
    if metric.HasField("histogram"):
        _shade_bins(axis, values, metric.histogram)
    for r in range(values.shape[0]):
        axis.plot(scene.steps, values[r], color=_SIM, lw=0.6, alpha=0.25)
    with warnings.catch_warnings():  # a step where no rollout has the feature: no median there
        warnings.simplefilter("ignore", RuntimeWarning)
        axis.plot(scene.steps, np.nanmedian(values, axis=0), color=_SIM, lw=1.4, label="rollouts (median)")
    reference = np.asarray(getattr(scene.log, feature), dtype=np.float64)[0, scene.e]
    log_valid = scene.log_valid
    axis.plot(
        scene.steps,
        np.where(log_valid & np.isfinite(reference), reference, np.nan),
        color=_LOG,
        lw=1.6,
        ls=(0, (4, 2)),
        label="logged",
    )
    simulated = values[np.isfinite(values)]
    logged_values = reference[np.isfinite(reference) & log_valid]
    if simulated.size or logged_values.size:
        # The log whole, the rollouts' bulk (not a far-away outlier: distances saturate far from anything).
        bounds = [np.percentile(simulated, [1, 99])] if simulated.size else []
        bounds += [np.array([logged_values.min(), logged_values.max()])] if logged_values.size else []
        low, high = min(b[0] for b in bounds), max(b[1] for b in bounds)
        margin = 0.08 * max(high - low, 1e-3)
        axis.set_ylim(low - margin, high + margin)
    axis.set_title(f"{title} ({unit}); shaded: the likelihood's bins, by the rollouts' share", fontsize=9)
    axis.tick_params(labelsize=7)
    if feature == PANELS[0][0]:
        axis.legend(fontsize=7, loc="upper right", framealpha=0.85)
    if feature == PANELS[-1][0]:
        axis.set_xlabel("scenario step (10 Hz)", fontsize=8)
