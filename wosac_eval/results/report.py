"""A self-contained HTML report of one scoring run, optionally compared with a baseline.

The page loads nothing from anywhere: styles are inline and the plots are PNGs
drawn with matplotlib's Agg canvas (no pyplot, so no global backend is touched)
and embedded as base64 `data:` URIs. It can be attached to a CI run, mailed, or
opened offline.

Sections (each an element with this id): `headline`, `buckets`, `rates`,
`distributions`, `worst`, `comparison` (only with a baseline), `skipped`; and, when the
result has them, `criticality`, `scenes` and `worst-objects` (a result scored with
`score --per-object`: the objects that cost each bucket most, `results.worst_objects`).
"""

from __future__ import annotations

import base64
import datetime
import html
from collections.abc import Iterable

import numpy as np

from wosac_eval.analysis.criticality_scores import LONG_TAIL_QUANTILE
from wosac_eval.metrics.registry import DISPLAY_ORDER
from wosac_eval.results.compare import BETTER, WORSE, Comparison
from wosac_eval.results.report_plots import (
    RATE_LABELS,
    bucket_plot,
    criticality_plot,
    distribution_plot,
    forest_plot,
    metric_label,
    metric_values,
    present_values,
    rate_plot,
    scatter_plot,
)
from wosac_eval.results.worst_objects import worst_objects
from wosac_eval.scoring.result_reader import (
    BUCKET_FIELDS,
    RATE_FIELDS,
    ScoringResult,
    higher_is_better,
    shared_rows,
)

SECTIONS = ("headline", "buckets", "rates", "distributions", "worst", "comparison", "skipped")

# Metrics whose per-scenario distribution and worst scenarios the report shows: all but the mean ADE
# (the leaderboard's displacement figure is the min ADE).
DISTRIBUTION_METRICS = tuple(f for f in DISPLAY_ORDER if f != "average_displacement_error")

_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:0;color:#1b1f24;background:#f6f8fa}
main{max-width:1200px;margin:0 auto;padding:16px 24px 48px}
h1{font-size:1.5rem;margin:8px 0 4px}h2{font-size:1.2rem;margin:0 0 12px}
section{background:#fff;border:1px solid #d0d7de;border-radius:8px;padding:16px 20px;margin:16px 0}
.meta{color:#57606a;font-size:.9rem}
.score{font-size:2.6rem;font-weight:600;margin:4px 16px 4px 0}
.cards{display:flex;flex-wrap:wrap;gap:12px;align-items:baseline}
.card{border:1px solid #d0d7de;border-radius:6px;padding:8px 14px;min-width:150px}
.card .v{font-size:1.3rem;font-weight:600}.card .k{color:#57606a;font-size:.8rem}
table{border-collapse:collapse;font-size:.88rem;margin:6px 0}
th,td{padding:3px 8px;border-bottom:1px solid #eaeef2;text-align:left}
td.n,th.n{text-align:right;font-variant-numeric:tabular-nums}
.better{color:#1a7f37;font-weight:600}.worse{color:#cf222e;font-weight:600}.same{color:#57606a}
.warn{background:#fff8c5;border:1px solid #d4a72c;border-radius:6px;padding:6px 10px;margin:6px 0}
.pass{color:#1a7f37;font-weight:600}.fail{color:#cf222e;font-weight:600}
details{margin:4px 0}summary{cursor:pointer;font-weight:600}
.row{display:flex;flex-wrap:wrap;gap:8px 32px;align-items:center}
figure.scene{margin:0 0 18px}figure.scene img{max-width:100%;border:1px solid #d0d7de}
.worst-grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(360px,1fr));gap:4px 24px}
img{max-width:100%;height:auto}
code{font-size:.85rem}
"""


def _esc(x: object) -> str:
    return html.escape(str(x), quote=True)


def _num(x: float | None, digits: int = 4, signed: bool = False) -> str:
    if x is None:
        return "-"
    x = round(x, digits) or 0.0  # no "-0.0000" for a change that rounds away
    return f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}"


def _pct(x: float | None, digits: int) -> str:
    return "-" if x is None else f"{100 * x:.{digits}f}%"


# ------------------------------------------------------------------------------------------------
# Sections


def _section(sid: str, title: str, body: Iterable[str]) -> str:
    return f'<section id="{sid}"><h2>{_esc(title)}</h2>{"".join(body)}</section>'


def _headline(result: ScoringResult, base: ScoringResult | None, comparison: Comparison | None) -> str:
    score = result.headline("realism_meta_metric")
    cards = [f'<div class="score">{_num(score)}</div>']
    if comparison is not None:
        m = next((m for m in comparison.metrics if m.metric == "metametric"), None)
        if m is not None:
            cls = {BETTER: "better", WORSE: "worse"}.get(m.verdict, "same")
            cards.append(
                f'<div class="card"><div class="k">vs baseline (paired, {comparison.num_shared} scenarios)'
                f'</div><div class="v {cls}">{_num(m.difference, signed=True)} &middot; {_esc(m.verdict)}'
                f"</div></div>"
            )
    cards.append(
        f'<div class="card"><div class="k">scenarios scored</div><div class="v">{result.num_scenarios}</div></div>'
    )
    cards.append(
        f'<div class="card"><div class="k">scenarios skipped</div><div class="v">{len(result.skipped)}</div></div>'
    )
    cards.append(
        f'<div class="card"><div class="k">min ADE (m)</div><div class="v">'
        f"{_num(result.headline('min_ade'))}</div></div>"
    )
    body = [
        f'<p class="meta">Realism meta-metric (the leaderboard score), config <code>{_esc(result.config)}</code></p>',
        f'<div class="cards">{"".join(cards)}</div>',
    ]
    return _section("headline", "Headline score", body)


def _bucket_section(result: ScoringResult, base: ScoringResult | None) -> str:
    names = list(BUCKET_FIELDS)
    head = (
        "<tr><th>bucket</th><th class=n>this run</th>"
        + ("<th class=n>baseline</th><th class=n>diff</th>" if base is not None else "")
        + "<th>better if</th></tr>"
    )
    rows = []
    for name in names:
        v = result.headline(name)
        cells = f"<td>{_esc(name)}</td><td class=n>{_num(v)}</td>"
        if base is not None:
            b = base.headline(name)
            cells += (
                f"<td class=n>{_num(b)}</td><td class=n>"
                + (_num(v - b, signed=True) if v is not None and b is not None else "-")
                + "</td>"
            )
        cells += f"<td>{'higher' if BUCKET_FIELDS[name] else 'lower'}</td>"
        rows.append(f"<tr>{cells}</tr>")
    note = (
        '<p class="meta">Baseline figures are each file\'s own aggregate over all its scenarios; the paired '
        "comparison below uses only the scenarios both share.</p>"
        if base is not None
        else ""
    )
    table = f"<table>{head}{''.join(rows)}</table>"
    return _section("buckets", "Buckets", [f'<div class="row">{bucket_plot(result, base)}{table}</div>', note])


def _rate_section(result: ScoringResult, base: ScoringResult | None) -> str:
    rows = []
    for r in RATE_FIELDS:
        v = result.headline(r)
        worst = float(result.values[r].max()) if result.num_scenarios else None
        share = float((result.values[r] > 0).mean()) if result.num_scenarios else None
        b = f"<td class=n>{_pct(base.headline(r), 2)}</td>" if base is not None else ""
        rows.append(
            f"<tr><td>{RATE_LABELS[r]}</td><td class=n>{_pct(v, 2)}</td>{b}"
            f"<td class=n>{_pct(share, 1)}</td><td class=n>{_pct(worst, 1)}</td></tr>"
        )
    head = (
        "<tr><th>rate</th><th class=n>this run</th>"
        + ("<th class=n>baseline</th>" if base is not None else "")
        + "<th class=n>scenarios with any</th><th class=n>worst scenario</th></tr>"
    )
    return _section(
        "rates",
        "Collision, offroad and red-light rates",
        [f'<div class="row">{rate_plot(result, base)}<table>{head}{"".join(rows)}</table></div>'],
    )


def _available(result: ScoringResult, base: ScoringResult | None) -> list[str]:
    return [
        m
        for m in DISTRIBUTION_METRICS
        if metric_values(result, m) is not None and (base is None or metric_values(base, m) is not None)
    ]


def _distribution_section(result: ScoringResult, base: ScoringResult | None) -> str:
    if result.num_scenarios == 0:
        return _section("distributions", "Per-scenario distributions", ["<p>No scenarios.</p>"])
    metrics = _available(result, base)
    note = (
        '<p class="meta">Histograms over scenarios; red line: mean.'
        + (" Outline: baseline." if base is not None else "")
        + "</p>"
    )
    return _section("distributions", "Per-scenario distributions", [note, distribution_plot(result, base, metrics)])


def _worst_section(result: ScoringResult, top_k: int) -> str:
    blocks = []
    for k, metric in enumerate(m for m in DISTRIBUTION_METRICS if metric_values(result, m) is not None):
        v = present_values(result, metric)
        order = np.argsort(v if higher_is_better(metric) else -v, kind="stable")[:top_k]
        rows = "".join(
            f"<tr><td class=n>{r + 1}</td><td><code>{_esc(result.scenario_ids[i])}</code></td>"
            f"<td class=n>{v[i]:.4f}</td></tr>"
            for r, i in enumerate(order)
        )
        direction = "lowest" if higher_is_better(metric) else "highest"
        blocks.append(
            f'<details{" open" if k == 0 else ""} data-metric="{_esc(metric)}"><summary>{_esc(metric)}'
            f" &mdash; {direction} {len(order)}</summary><table><tr><th class=n>#</th><th>scenario</th>"
            f"<th class=n>value</th></tr>{rows}</table></details>"
        )
    return _section(
        "worst", f"Worst scenarios per metric (top {top_k})", [f'<div class="worst-grid">{"".join(blocks)}</div>']
    )


def _worst_objects_section(result: ScoringResult, top_k: int) -> str:
    """Per bucket, the objects contributing most to its gap from 1, with the fields that sink them."""
    try:
        worst = worst_objects(result, top_k)
    except FileNotFoundError:
        return _section(
            "worst-objects",
            "Worst objects",
            [
                f'<p class="warn">The per-object file <code>{_esc(result.objects)}</code> the result names is missing '
                "(keep it beside the result).</p>"
            ],
        )
    blocks = []
    for k, (bucket, objects) in enumerate(worst.items()):
        gap = 1.0 - (result.headline(bucket) or 0.0)
        rows = []
        for r, o in enumerate(objects):
            sunk = ", ".join(
                f"{_esc(metric_label(f))} {value:.3g} ({part / o.contribution:.0%})" for f, value, part in o.fields[:3]
            )
            share = f"{o.contribution / gap:.1%}" if gap > 0 else "-"
            rows.append(
                f"<tr><td class=n>{r + 1}</td><td><code>{_esc(o.scenario_id)}</code></td>"
                f"<td class=n>{o.object_id}</td><td>{_esc(o.object_type)}</td>"
                f"<td class=n>{o.contribution:.5f}</td><td class=n>{share}</td><td>{sunk}</td></tr>"
            )
        blocks.append(
            f'<details{" open" if k == 0 else ""} data-bucket="{_esc(bucket)}"><summary>'
            f"{_esc(metric_label(bucket.removesuffix('_metrics')))} (gap from 1: {gap:.4f})</summary><table>"
            "<tr><th class=n>#</th><th>scenario</th><th class=n>object</th><th>type</th>"
            "<th class=n>part of the gap</th><th class=n>share</th><th>sunk by (likelihood, share)</th></tr>"
            f"{''.join(rows)}</table></details>"
        )
    note = (
        "<p class=\"meta\">Each bucket's gap from 1 split exactly over the evaluated objects: a scene's "
        "field is the count-weighted geometric mean of its objects' likelihoods, so its gap is shared in "
        "proportion to each object's weighted -log likelihood. Sunk by: the object's likelihoods that "
        "cost most, with their share of its part.</p>"
    )
    return _section("worst-objects", f"Worst objects per bucket (top {top_k})", [note, *blocks])


def worst_scenarios(result: ScoringResult, count: int, metric: str = "metametric") -> list[str]:
    """Ids of the `count` scenarios with the lowest meta-metric (the scenes worth looking at first)."""
    values = metric_values(result, metric)
    if values is None:
        return []
    return [str(result.scenario_ids[i]) for i in np.argsort(values, kind="stable")[:count]]


def _scenes_section(result: ScoringResult, scenes: list[tuple[str, bytes]]) -> str:
    """The pictures of the worst scenes (`wosac-eval plot` at the step of the last event)."""
    values = metric_values(result, "metametric")
    where = {sid: i for i, sid in enumerate(result.scenario_ids.tolist())}
    cards = []
    for scenario_id, png in scenes:
        score = f"meta-metric {values[where[scenario_id]]:.4f}" if values is not None and scenario_id in where else ""
        data = base64.b64encode(png).decode("ascii")
        cards.append(
            f'<figure class="scene" data-scenario="{_esc(scenario_id)}"><img alt="scenario '
            f'{_esc(scenario_id)}" src="data:image/png;base64,{data}"><figcaption><code>{_esc(scenario_id)}'
            f"</code> {score}</figcaption></figure>"
        )
    note = (
        '<p class="meta">The lowest meta-metric scenes: map, log (dashed), rollouts 0 to 2, boxes of rollout 0 '
        "at the last event; crosses collisions, triangles off-road, squares red-light runs "
        "(`wosac-eval plot` draws any scene, as .png, .gif or .html).</p>"
    )
    return _section("scenes", f"Worst scenes ({len(scenes)})", [note, "".join(cards)])


def _criticality_section(result: ScoringResult, c: np.ndarray, top_k: int) -> str:
    """Realism against the scenes' criticality `c` (`result.criticality`), and the worst long-tail scenes."""
    m = result.values["metametric"]
    tail = float(np.quantile(c, LONG_TAIL_QUANTILE))
    in_tail = np.flatnonzero(c >= tail)
    worst = in_tail[np.argsort(m[in_tail], kind="stable")][:top_k]
    rows = "".join(
        f"<tr><td class=n>{r + 1}</td><td><code>{_esc(result.scenario_ids[i])}</code></td>"
        f"<td class=n>{c[i]:.3f}</td><td class=n>{m[i]:.4f}</td></tr>"
        for r, i in enumerate(worst)
    )
    rest = np.flatnonzero(c < tail)
    summary = (
        f"<p class=meta>Long tail: the {in_tail.size} scenario(s) with criticality &ge; {tail:.3f} "
        f"(top decile): mean meta-metric {m[in_tail].mean():.4f}"
        + (f" against {m[rest].mean():.4f} for the other {rest.size}" if rest.size else "")
        + ". Criticality rates the logged scene alone (braking, jerk, time to collision, near misses, "
        "off-road, red lights, rarity); `wosac-eval compare --stratify criticality` tests the "
        "difference between two runs per stratum.</p>"
    )
    table = (
        f"<table data-table=long-tail><tr><th class=n>#</th><th>worst long-tail scenario</th>"
        f"<th class=n>criticality</th><th class=n>meta-metric</th></tr>{rows}</table>"
    )
    return _section("criticality", "Realism against criticality", [summary, criticality_plot(result, c, tail), table])


def _changed_scenarios(result: ScoringResult, base: ScoringResult, top_k: int) -> str:
    """Tables of the scenarios whose meta-metric dropped / rose the most: where to look first."""
    bi, ni = shared_rows(base, result)
    if bi.size == 0:
        return ""
    b, n = base.values["metametric"][bi], result.values["metametric"][ni]
    change = n - b
    order = np.argsort(change, kind="stable")
    tables = []
    for title, picks in (("largest drops", order[:top_k]), ("largest gains", order[::-1][:top_k])):
        rows = "".join(
            f"<tr><td><code>{_esc(result.scenario_ids[ni[j]])}</code></td><td class=n>{b[j]:.4f}</td>"
            f"<td class=n>{n[j]:.4f}</td><td class=n>{change[j]:+.4f}</td></tr>"
            for j in picks
        )
        tables.append(
            f'<div data-changes="{title.split()[1]}"><h3>Meta-metric: {title}</h3><table><tr>'
            f"<th>scenario</th><th class=n>baseline</th><th class=n>this run</th><th class=n>change</th>"
            f"</tr>{rows}</table></div>"
        )
    return f'<div class="row">{"".join(tables)}</div>'


def _comparison_section(result: ScoringResult, base: ScoringResult, c: Comparison, top_k: int) -> str:
    body = [
        f'<p class="meta">Baseline <code>{_esc(c.base_path)}</code> (config <code>{_esc(c.base_config)}</code>). '
        f"Paired over {c.num_shared} shared scenarios ({c.num_base_only} only in baseline, {c.num_new_only} only "
        f"in this run); diff = this run - baseline; {c.n_boot} bootstrap resamples, "
        + ("exact permutation test" if c.exact_permutation else f"{c.n_perm} random sign flips")
        + f", seed {c.seed}, alpha {c.alpha:g}"
        + (", Holm-adjusted" if c.adjust == "holm" else "")
        + ".</p>"
    ]
    body += [f'<div class="warn">{_esc(w)}</div>' for w in c.warnings]
    conf = f"{round((1 - c.alpha) * 100):d}% CI"
    rows = []
    for m in c.metrics:
        cls = {BETTER: "better", WORSE: "worse"}.get(m.verdict, "same")
        p = m.p_holm if c.adjust == "holm" else m.p_value
        ci = f"[{_num(m.ci_low, signed=True)}, {_num(m.ci_high, signed=True)}]" if m.paired else "-"
        rows.append(
            f"<tr><td>{_esc(m.metric)}</td><td>{'higher' if m.higher_is_better else 'lower'}</td>"
            f"<td class=n>{_num(m.base)}</td><td class=n>{_num(m.new)}</td>"
            f"<td class=n>{_num(m.difference, signed=True)}</td><td class=n>{ci}</td>"
            f"<td class=n>{'-' if p is None else f'{p:.4f}'}</td><td class={cls}>{_esc(m.verdict)}</td></tr>"
        )
    body.append(
        "<table><tr><th>metric</th><th>better if</th><th class=n>baseline</th><th class=n>this run</th>"
        f"<th class=n>diff</th><th class=n>{conf}</th><th class=n>p</th><th>verdict</th></tr>"
        + "".join(rows)
        + "</table>"
    )
    tested = sum(1 for m in c.metrics if m.paired)
    if tested > 1 and c.adjust != "holm":
        body.append(
            f'<p class="meta">{tested} metrics tested with unadjusted p-values: with no real change about '
            f"{tested * c.alpha:.1f} can still come out better/worse by chance.</p>"
        )
    if c.gates:
        gates = "".join(
            f"<li><code>{_esc(g.gate.spec)}</code> "
            f"<span class={'pass' if g.passed else 'fail'}>{'PASS' if g.passed else 'FAIL'}</span> "
            f"{_esc(g.reason)}</li>"
            for g in c.gates
        )
        body.append(f"<h3>Gates</h3><ul>{gates}</ul>")
    plots = [p for p in (forest_plot(c), scatter_plot(result, base)) if p]
    body.append('<div class="cards">' + "".join(plots) + "</div>")
    body.append(_changed_scenarios(result, base, top_k))
    return _section("comparison", "Comparison with the baseline", body)


def _skipped_section(result: ScoringResult) -> str:
    if not result.skipped:
        return _section("skipped", "Skipped scenarios", ["<p>None: every scenario was scored.</p>"])
    rows = "".join(
        f"<tr><td><code>{_esc(s.get('scenario_id', ''))}</code></td><td>{_esc(s.get('reason', ''))}</td></tr>"
        for s in result.skipped
    )
    return _section(
        "skipped",
        f"Skipped scenarios ({len(result.skipped)})",
        [f"<table><tr><th>scenario</th><th>reason</th></tr>{rows}</table>"],
    )


def render_report(
    result: ScoringResult,
    base: ScoringResult | None = None,
    comparison: Comparison | None = None,
    top_k: int = 10,
    title: str | None = None,
    scenes: list[tuple[str, bytes]] | None = None,
) -> str:
    """The report as one HTML document (a string with no external references).

    Args:
      result: the run to report on.
      base: a baseline run; with `comparison` (from `compare_results(base, result)`)
        adds the comparison section and baseline overlays.
      top_k: how many worst scenarios to list per metric.
      scenes: (scenario_id, PNG) pictures of scenes to show (e.g. of `worst_scenarios`).
    """
    if (base is None) != (comparison is None):
        raise ValueError("pass both the baseline result and its comparison, or neither")
    title = title or f"WOSAC evaluation report: {result.path}"
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    parts = [
        _headline(result, base, comparison),
        _bucket_section(result, base),
        _rate_section(result, base),
    ]
    if base is not None and comparison is not None:  # both or neither (checked above)
        parts.append(_comparison_section(result, base, comparison, top_k))
    parts += [_distribution_section(result, base), _worst_section(result, top_k)]
    if result.objects is not None and result.num_scenarios > 0:
        parts.append(_worst_objects_section(result, top_k))
    if result.criticality is not None and result.num_scenarios > 0:
        parts.append(_criticality_section(result, result.criticality, top_k))
    if scenes:
        parts.append(_scenes_section(result, scenes))
    parts.append(_skipped_section(result))
    return (
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
        f"<meta name=viewport content='width=device-width,initial-scale=1'><title>{_esc(title)}</title>"
        f"<style>{_CSS}</style></head><body><main><h1>{_esc(title)}</h1>"
        f'<p class="meta">Generated by wosac-eval on {now} from <code>{_esc(result.path)}</code></p>'
        + "".join(parts)
        + "</main></body></html>\n"
    )
