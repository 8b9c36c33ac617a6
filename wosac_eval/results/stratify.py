"""Stratified comparison: where two runs differ, by scenario criticality or by object type.

Each stratum is a paired comparison of its own (`stats.paired_test` on the
scenarios of the stratum scored in both runs) with the effect size, Cohen's d
of the paired differences (d_z = mean / standard deviation), so that a small
long tail with a large change is visible beside the mean over all scenarios.

- by criticality: terciles of the criticality score (low, mid, high) and the
  long tail (top decile) against the rest. The score comes from the base run
  (the new run's if the base has none): strata are the same scenarios for both.
- by object type: per type, the type's own metrics (`by_object_type` of each
  row) over the scenarios where both runs have that type evaluated.

Every (stratum, metric) pair is a test: p-values are also given Holm-adjusted
over all of them, and the note says how many were run.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from wosac_eval.analysis.criticality_scores import LONG_TAIL_QUANTILE
from wosac_eval.arrays.object_types import ANALYSED_TYPES
from wosac_eval.results import stats
from wosac_eval.results.stats import PairedSettings
from wosac_eval.scoring.result_reader import ScoringResult, higher_is_better, shared_rows

STRATIFY = ("criticality", "object_type")


class StratifyError(ValueError):
    """The results cannot be stratified as asked (no criticality, no per-type values, unknown metric)."""


@dataclasses.dataclass(frozen=True)
class StratumComparison:
    """One metric over one stratum: paired means, difference (new - base), CI, p-values, Cohen's d, verdict."""

    stratum: str
    description: str
    metric: str
    num_scenarios: int
    base: float | None
    new: float | None
    difference: float | None
    ci_low: float | None
    ci_high: float | None
    p_value: float | None
    p_holm: float | None
    cohens_d: float | None
    verdict: str


@dataclasses.dataclass(frozen=True)
class Stratification:
    by: str
    alpha: float
    rows: list[StratumComparison]
    notes: list[str]

    def to_json(self) -> dict[str, Any]:
        return {
            "by": self.by,
            "alpha": self.alpha,
            "strata": [dataclasses.asdict(r) for r in self.rows],
            "notes": list(self.notes),
        }


def cohens_d(differences: np.ndarray) -> float | None:
    """Paired effect size d_z: mean / sample standard deviation of the differences (None if undefined)."""
    if differences.size < 2:
        return None
    spread = float(np.std(differences, ddof=1))
    mean = float(np.mean(differences))
    if spread == 0.0:
        return 0.0 if mean == 0.0 else None
    return mean / spread


def criticality_strata(scores: np.ndarray) -> list[tuple[str, str, np.ndarray]]:
    """(name, description, mask) of the terciles and of the long tail and the rest."""
    low, high = np.quantile(scores, [1 / 3, 2 / 3])
    tail = np.quantile(scores, LONG_TAIL_QUANTILE)
    return [
        ("low", f"criticality <= {low:.3f} (lowest third)", scores <= low),
        ("mid", f"{low:.3f} < criticality <= {high:.3f}", (scores > low) & (scores <= high)),
        ("high", f"criticality > {high:.3f} (highest third)", scores > high),
        ("long tail", f"criticality >= {tail:.3f} (top decile)", scores >= tail),
        ("rest", f"criticality < {tail:.3f}", scores < tail),
    ]


def _compare(
    stratum: str, description: str, metric: str, base: np.ndarray, new: np.ndarray, settings: PairedSettings
) -> StratumComparison:
    if base.size == 0:
        return StratumComparison(
            stratum, description, metric, 0, None, None, None, None, None, None, None, None, "n/a (no scenario)"
        )
    test = settings.test(base, new)
    return StratumComparison(
        stratum,
        description,
        metric,
        int(base.size),
        float(base.mean()),
        float(new.mean()),
        float(test.mean_difference[0]),
        float(test.ci_low[0]),
        float(test.ci_high[0]),
        float(test.p_value[0]),
        None,
        cohens_d(new - base),
        "",
    )


def _with_verdicts(rows: list[StratumComparison], settings: PairedSettings) -> list[StratumComparison]:
    p_values = {i: r.p_value for i, r in enumerate(rows) if r.p_value is not None}
    tested = list(p_values)
    adjusted = stats.holm_adjust(np.array(list(p_values.values()))) if tested else np.empty(0)
    out = list(rows)
    for i, p_holm in zip(tested, adjusted):
        r = rows[i]
        if (
            p_holm if settings.adjust == "holm" else p_values[i]
        ) >= settings.alpha or not r.difference:  # tested: a difference
            verdict = "no significant difference"
        else:
            verdict = "better" if (r.difference > 0) == higher_is_better(r.metric) else "worse"
        out[i] = dataclasses.replace(r, p_holm=float(p_holm), verdict=verdict)
    return out


def stratified_comparison(
    base: ScoringResult,
    new: ScoringResult,
    by: str,
    metrics: list[str],
    settings: PairedSettings | None = None,
) -> Stratification:
    """Paired comparisons of `metrics` per stratum (see the module); raises StratifyError if impossible.

    settings: the paired tests' (`stats.PairedSettings`; None: the defaults). Verdicts come from the raw
    p-values, or from the Holm-adjusted ones with `adjust="holm"`.
    """
    settings = PairedSettings() if settings is None else settings
    if by not in STRATIFY:
        raise StratifyError(f"--stratify {by!r}: choose {' or '.join(STRATIFY)}")
    base_rows, new_rows = shared_rows(base, new)
    if base_rows.size == 0:
        raise StratifyError("the results share no scenario")
    rows: list[StratumComparison] = []
    if by == "criticality":
        source = base if base.criticality is not None else new
        if source.criticality is None:
            raise StratifyError(
                f"neither {base.path} nor {new.path} carries criticality scores: score them "
                "again with this version (every row then has `criticality`)"
            )
        scores = source.criticality[base_rows if source is base else new_rows]
        for metric in metrics:
            if not (base.has_per_scenario(metric) and new.has_per_scenario(metric)):
                raise StratifyError(f"metric {metric!r} has no per-scenario values in both results")
            b, n = base.per_scenario(metric)[base_rows], new.per_scenario(metric)[new_rows]
            for name, description, mask in criticality_strata(scores):
                rows.append(_compare(name, description, metric, b[mask], n[mask], settings))
    else:
        kinds = [k for k in ANALYSED_TYPES if k in base.by_type and k in new.by_type]
        if not kinds:
            raise StratifyError(
                f"{base.path} and {new.path} share no per-object-type values (`by_object_type`): "
                "score them again with this version"
            )
        for metric in metrics:
            for kind in kinds:
                if metric not in base.by_type[kind] or metric not in new.by_type[kind]:
                    continue
                b = base.by_type[kind][metric][base_rows]
                n = new.by_type[kind][metric][new_rows]
                both = np.isfinite(b) & np.isfinite(n)
                rows.append(
                    _compare(
                        kind,
                        f"scenarios with evaluated {kind}s; their {metric}",
                        metric,
                        b[both],
                        n[both],
                        settings,
                    )
                )
        if not rows:
            raise StratifyError(f"no per-object-type values of {', '.join(metrics)} in both results")
    rows = _with_verdicts(rows, settings)
    alpha = settings.alpha
    tested = sum(r.p_value is not None for r in rows)
    notes = [
        f"{tested} tests (strata x metrics) at alpha={alpha:g}: about {tested * alpha:.1f} can come out "
        "better/worse by chance alone; p_holm controls the family-wise error over all of them."
        + (
            " The strata overlap (terciles; long tail and rest), so the tests are not independent."
            if by == "criticality"
            else ""
        )
    ]
    if any(r.num_scenarios and r.num_scenarios < 30 for r in rows):
        notes.append("strata with fewer than 30 scenarios have rough intervals and p-values")
    return Stratification(by, alpha, rows, notes)


def format_strata(s: Stratification) -> str:
    """The stratified comparison as a plain-text table, with its notes."""
    header = [
        "stratum",
        "metric",
        "n",
        "base",
        "new",
        "diff",
        f"{round((1 - s.alpha) * 100)}% CI",
        "p",
        "p_holm",
        "d",
        "verdict",
    ]

    def f(x: float | None, signed: bool = False) -> str:
        return "-" if x is None else (f"{x:+.4f}" if signed else f"{x:.4f}")

    body = [
        [
            r.stratum,
            r.metric,
            str(r.num_scenarios),
            f(r.base),
            f(r.new),
            f(r.difference, True),
            "-" if r.ci_low is None else f"[{r.ci_low:+.4f}, {r.ci_high:+.4f}]",
            "-" if r.p_value is None else f"{r.p_value:.3g}",
            "-" if r.p_holm is None else f"{r.p_holm:.3g}",
            "-" if r.cohens_d is None else f"{r.cohens_d:+.2f}",
            r.verdict.upper() if r.verdict == "worse" else r.verdict,
        ]
        for r in s.rows
    ]
    widths = [max(len(row[i]) for row in [header] + body) for i in range(len(header))]
    line = lambda cells: "  ".join(c.ljust(w) for c, w in zip(cells, widths)).rstrip()  # noqa: E731
    out = [f"stratified by {s.by.replace('_', ' ')}:"]
    out += [f"  {r.stratum}: {r.description}" for r in s.rows if r.metric == s.rows[0].metric]
    out += ["", line(header), line(["-" * w for w in widths]), *map(line, body), ""]
    out += [f"note: {n}" for n in s.notes]
    return "\n".join(out)
