"""The report's plots: matplotlib figures drawn on the Agg canvas (no pyplot, so no global backend is touched),
each returned as an `<img>` with a base64 PNG data URI (`results.report` lays them out)."""

from __future__ import annotations

import base64
import io
from typing import TYPE_CHECKING, Any

import numpy as np

from wosac_eval.metrics.registry import RATES, SCORE_BUCKETS
from wosac_eval.results.compare import BETTER, WORSE, Comparison
from wosac_eval.scoring.result_reader import BUCKET_ALIASES, RATE_FIELDS, ScoringResult, shared_rows

if TYPE_CHECKING:  # matplotlib is loaded when a plot is drawn (in the functions that draw)
    from matplotlib.figure import Figure

RATE_LABELS = {rate.name: rate.title for rate in RATES}
BASE_COLOR, NEW_COLOR = "#9aa5b1", "#1f6feb"


def png(fig: Figure, tight: bool = True) -> str:
    """The figure as an `<img>` with a base64 PNG data URI.

    `tight` crops to the drawn content, at the cost of one more drawing pass
    (large grids of subplots set their margins by hand instead).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight" if tight else None, metadata={"Software": None})
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="plot" src="data:image/png;base64,{data}">'


def figure(width: float, height: float) -> Any:  # a Figure; Any: the drawing code is not typed for matplotlib's stubs
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height))


def metric_label(metric: str) -> str:
    return metric.removesuffix("_likelihood").replace("_", " ")


def metric_values(result: ScoringResult, metric: str) -> np.ndarray | None:
    key = BUCKET_ALIASES.get(metric, metric)
    return result.values.get(key)


def present_values(result: ScoringResult, metric: str) -> np.ndarray:
    """`metric_values` of a metric the caller knows the result has (`_available`)."""
    values = metric_values(result, metric)
    if values is None:
        raise KeyError(f"the result has no per-scenario {metric}")
    return values


def _legend_above(ax: Any) -> None:
    """The legend above the axes, outside them: inside it would cover a bar whatever corner it took."""
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, fontsize=8, frameon=False, borderaxespad=0.2)


def bucket_plot(result: ScoringResult, base: ScoringResult | None) -> str:
    fig = bucket_figure(result, base)
    return png(fig) if fig is not None else ""


def bucket_figure(result: ScoringResult, base: ScoringResult | None) -> Any:  # a Figure or None (see `figure`)
    """Horizontal bars of the bucket scores (this run, and the baseline's beside them); None without buckets."""
    names = [b for b in SCORE_BUCKETS if result.headline(b) is not None]
    if not names:
        return None
    fig = figure(5.6, 2.6)
    ax = fig.add_subplot()
    y = np.arange(len(names))
    height = 0.38 if base is not None else 0.6
    new_vals = [result.headline(n) or 0.0 for n in names]  # each present (`names`)
    ax.barh(y, new_vals, height=height, color=NEW_COLOR, label="this run")
    if base is not None:
        base_vals = [base.headline(n) or 0.0 for n in names]
        ax.barh(y + height, base_vals, height=height, color=BASE_COLOR, label="baseline")
        _legend_above(ax)
    for yi, v in zip(y, new_vals):
        ax.text(v + 0.01, yi, f"{v:.4f}", va="center", fontsize=8)
    ax.set_yticks(y + (height / 2 if base is not None else 0), [metric_label(n) for n in names])
    ax.invert_yaxis()
    ax.set_xlim(0, 1.08)
    ax.set_xlabel("score (higher is better)")
    ax.grid(axis="x", alpha=0.3)
    return fig


def rate_plot(result: ScoringResult, base: ScoringResult | None) -> str:
    fig = figure(4.6, 2.0)
    ax = fig.add_subplot()
    y = np.arange(len(RATE_FIELDS))
    height = 0.38 if base is not None else 0.6
    vals = [100 * (result.headline(r) or 0.0) for r in RATE_FIELDS]
    ax.barh(y, vals, height=height, color="#d1242f", label="this run")
    if base is not None:
        ax.barh(
            y + height,
            [100 * (base.headline(r) or 0.0) for r in RATE_FIELDS],
            height=height,
            color=BASE_COLOR,
            label="baseline",
        )
        _legend_above(ax)
    for yi, v in zip(y, vals):
        ax.text(v, yi, f" {v:.2f}%", va="center", fontsize=8)
    ax.set_yticks(y + (height / 2 if base is not None else 0), [RATE_LABELS[r] for r in RATE_FIELDS])
    ax.invert_yaxis()
    ax.set_xlim(0, max(vals + [1.0]) * 1.25)
    ax.set_xlabel("% of simulated objects (lower is better)")
    ax.grid(axis="x", alpha=0.3)
    return png(fig)


def _histogram_bins(data: np.ndarray, count: int = 30) -> np.ndarray:
    """`count + 1` bin edges over the values; a single value (one scenario, or all equal) or a spread
    far below the values' scale gets a readable span around it instead of a sliver of 1e-6."""
    lo, hi = float(data.min()), float(data.max())
    scale = max(abs(lo), abs(hi), 0.2)
    if hi - lo < 1e-3 * scale:
        middle, pad = (lo + hi) / 2, 0.05 * scale
        lo, hi = middle - pad, middle + pad
    return np.linspace(lo, hi, count + 1)


def distribution_plot(result: ScoringResult, base: ScoringResult | None, metrics: list[str]) -> str:
    from matplotlib.ticker import MaxNLocator

    cols = 4
    rows = (len(metrics) + cols - 1) // cols
    fig = figure(14, 2.1 * rows)
    for k, metric in enumerate(metrics):
        ax = fig.add_subplot(rows, cols, k + 1)
        v = present_values(result, metric)
        b = present_values(base, metric) if base is not None else None
        data = np.concatenate([v, b]) if b is not None else v
        bins = _histogram_bins(data)
        # One artist per histogram (ax.hist draws a patch per bin, several times slower over 19 panels).
        ax.stairs(np.histogram(v, bins)[0], bins, fill=True, color=NEW_COLOR, alpha=0.75, label="this run")
        if b is not None:
            ax.stairs(np.histogram(b, bins)[0], bins, color="#444c56", linewidth=1.2, label="baseline")
        ax.axvline(float(v.mean()), color="#cf222e", linewidth=1)
        ax.set_title(f"{metric_label(metric)}  (mean {v.mean():.3f})", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(5))
        ax.xaxis.get_major_formatter().set_useOffset(False)  # never '1e-6+2.5824e-1' under the axis
        ax.yaxis.set_major_locator(MaxNLocator(4))
        if k == 0 and b is not None:
            ax.legend(fontsize=7)
    # Fixed margins: tight_layout would cost a full extra drawing pass over every subplot.
    fig.subplots_adjust(
        left=0.04, right=0.99, bottom=0.5 / (2.1 * rows), top=1 - 0.35 / (2.1 * rows), wspace=0.22, hspace=0.55
    )
    return png(fig, tight=False)


def forest_plot(comparison: Comparison) -> str | None:
    # Displacement errors are in metres, the rest in [0, 1]: they would crush the scale.
    rows = [m for m in comparison.metrics if m.paired and "displacement" not in m.metric]
    if not rows:
        return None
    fig = figure(8, 0.32 * len(rows) + 1.0)
    ax = fig.add_subplot()
    y = np.arange(len(rows))
    for yi, m in zip(y, rows):
        color = {BETTER: "#1a7f37", WORSE: "#cf222e"}.get(m.verdict, "#57606a")
        ax.plot([m.ci_low, m.ci_high], [yi, yi], color=color, linewidth=2)
        ax.plot([m.difference], [yi], "o", color=color, markersize=4)
    ax.axvline(0.0, color="#1b1f24", linewidth=0.8)
    ax.set_yticks(y, [metric_label(m.metric) for m in rows], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("new - base, mean over shared scenarios, with 95% CI", fontsize=9)
    ax.grid(axis="x", alpha=0.3)
    return png(fig)


def scatter_plot(result: ScoringResult, base: ScoringResult) -> str | None:
    bi, ni = shared_rows(base, result)
    if bi.size == 0:
        return None
    b, n = base.values["metametric"][bi], result.values["metametric"][ni]
    fig = figure(4.2, 4.0)
    ax = fig.add_subplot()
    ax.scatter(b, n, s=4, alpha=0.4 if b.size > 500 else 0.8, color=NEW_COLOR, edgecolors="none")
    lo, hi = float(min(b.min(), n.min())), float(max(b.max(), n.max()))
    ax.plot([lo, hi], [lo, hi], color="#1b1f24", linewidth=0.8)
    ax.set_xlabel("baseline meta-metric", fontsize=9)
    ax.set_ylabel("this run's meta-metric", fontsize=9)
    ax.set_title("per scenario (above the line: improved)", fontsize=9)
    ax.tick_params(labelsize=7)
    return png(fig)


def criticality_plot(result: ScoringResult, c: np.ndarray, tail: float) -> str:
    """`c`: the scenes' criticality scores (`result.criticality`)."""
    m = result.values["metametric"]
    fig = figure(5.0, 3.6)
    ax = fig.add_subplot()
    in_tail = c >= tail
    ax.scatter(
        c[~in_tail],
        m[~in_tail],
        s=5,
        alpha=0.5 if c.size > 500 else 0.8,
        color=NEW_COLOR,
        edgecolors="none",
        label="rest",
    )
    ax.scatter(c[in_tail], m[in_tail], s=9, color="#cf222e", edgecolors="none", label="long tail (top decile)")
    ax.axvline(tail, color="#1b1f24", linewidth=0.6, linestyle=":")
    if c.size > 2 and np.ptp(c) > 0:
        slope, intercept = np.polyfit(c, m, 1)
        xs = np.array([c.min(), c.max()])
        ax.plot(xs, slope * xs + intercept, color="#1b1f24", linewidth=0.8, label=f"trend (slope {slope:+.3f})")
    ax.set_xlabel("criticality of the logged scene", fontsize=9)
    ax.set_ylabel("meta-metric", fontsize=9)
    ax.tick_params(labelsize=7)
    _legend_above(ax)
    return png(fig)
