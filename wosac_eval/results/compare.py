"""Comparing two scoring runs: paired statistics per metric, verdicts and gates.

The comparison is paired: only scenarios scored in both runs count, and each
metric's difference is the mean over those scenarios of `new - base`. That is
what makes a 0.002 change in the meta-metric detectable on a few thousand
scenarios: scenario difficulty, which dominates the spread of the raw scores,
cancels out in the differences.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import numpy as np

from wosac_eval.metrics.registry import DISPLAY_ORDER
from wosac_eval.results import stats
from wosac_eval.results.stats import PairedSettings
from wosac_eval.scoring.result_reader import ScoringResult, higher_is_better, shared_rows

# Metrics in display order (the registry's).
METRICS: tuple[str, ...] = DISPLAY_ORDER

# Other names accepted on the command line (the leaderboard's bucket names).
ALIASES: dict[str, str] = {
    "realism_meta_metric": "metametric",
    "min_ade": "min_average_displacement_error",
    "ade": "average_displacement_error",
}

# When fewer scenarios than this are shared, intervals and p-values are rough.
FEW_SCENARIOS = 30

BETTER, WORSE, NO_DIFFERENCE, NOT_TESTED = "better", "worse", "no significant difference", "n/a (aggregate only)"


class CompareError(ValueError):
    """The two results cannot be compared (usage error, exit code 2)."""


def canonical_metric(name: str) -> str:
    """The canonical metric name for a user-given name or alias.

    Raises:
      CompareError: the name is unknown (the message lists the known names).
    """
    key = name.strip().lower()
    key = ALIASES.get(key, key)
    if key not in METRICS:
        raise CompareError(
            f"unknown metric {name!r}; known metrics: {', '.join(METRICS)} "
            f"(aliases: {', '.join(f'{a}={m}' for a, m in ALIASES.items())})"
        )
    return key


@dataclasses.dataclass(frozen=True)
class Gate:
    """`--fail-if-worse METRIC:DELTA`: fail when new is worse than base by more than DELTA.

    DELTA is in the metric's units, or with a `%` suffix a fraction of the
    baseline's value (`metametric:1%` tolerates a drop of 1% of the baseline).
    """

    metric: str
    delta: float
    relative: bool = False

    @classmethod
    def parse(cls, text: str) -> Gate:
        name, sep, delta = text.rpartition(":")
        if not sep or not name:
            raise CompareError(f"gate {text!r}: expected METRIC:DELTA, e.g. metametric:0.005 or metametric:1%")
        relative = delta.strip().endswith("%")
        try:
            value = float(delta.strip().removesuffix("%"))
        except ValueError:
            raise CompareError(f"gate {text!r}: DELTA {delta!r} is not a number (or a percentage)") from None
        if not np.isfinite(value) or value < 0:
            raise CompareError(f"gate {text!r}: DELTA must be a finite number >= 0 (the tolerated regression)")
        return cls(canonical_metric(name), value / 100 if relative else value, relative)

    @property
    def spec(self) -> str:
        return f"{self.metric}:{self.delta * 100:g}%" if self.relative else f"{self.metric}:{self.delta:g}"

    def allowed(self, base: float) -> float:
        """The tolerated regression, in the metric's units, for a baseline value."""
        return self.delta * abs(base) if self.relative else self.delta


@dataclasses.dataclass
class MetricComparison:
    """One metric of the comparison.

    `base` and `new` are means over the shared scenarios when `paired`; otherwise
    (the values exist only as file aggregates) each file's own aggregate, and the
    statistics are None.
    """

    metric: str
    higher_is_better: bool
    paired: bool
    base: float
    new: float
    difference: float
    ci_low: float | None = None
    ci_high: float | None = None
    p_value: float | None = None
    p_holm: float | None = None
    verdict: str = NOT_TESTED

    @property
    def regression(self) -> float:
        """How much worse new is than base (positive = worse), in the metric's units."""
        return -self.difference if self.higher_is_better else self.difference


@dataclasses.dataclass
class GateOutcome:
    gate: Gate
    regression: float | None  # None when the metric could not be compared (the gate then fails)
    passed: bool
    reason: str
    allowed: float | None = None  # the tolerated regression in the metric's units


@dataclasses.dataclass
class Comparison:
    base_path: str
    new_path: str
    base_config: str
    new_config: str
    challenge: str
    num_shared: int
    num_base_only: int
    num_new_only: int
    alpha: float
    adjust: str
    seed: int
    n_boot: int
    n_perm: int
    exact_permutation: bool
    metrics: list[MetricComparison]
    gates: list[GateOutcome]
    warnings: list[str]

    @property
    def passed(self) -> bool:
        return all(g.passed for g in self.gates)

    def metric(self, name: str) -> MetricComparison:
        name = canonical_metric(name)
        for m in self.metrics:
            if m.metric == name:
                return m
        raise KeyError(name)

    def to_json(self) -> dict[str, Any]:
        return {
            "challenge": self.challenge,
            "base": {"path": self.base_path, "config": self.base_config},
            "new": {"path": self.new_path, "config": self.new_config},
            "scenarios": {"shared": self.num_shared, "base_only": self.num_base_only, "new_only": self.num_new_only},
            "settings": {
                "alpha": self.alpha,
                "adjust": self.adjust,
                "seed": self.seed,
                "n_boot": self.n_boot,
                "n_perm": self.n_perm,
                "exact_permutation": self.exact_permutation,
                "difference": "new - base, mean over shared scenarios",
            },
            "metrics": [dataclasses.asdict(m) for m in self.metrics],
            "gates": [
                {
                    "gate": g.gate.spec,
                    "metric": g.gate.metric,
                    "max_regression": g.allowed,
                    "regression": g.regression,
                    "passed": g.passed,
                    "reason": g.reason,
                }
                for g in self.gates
            ],
            "warnings": list(self.warnings),
            "passed": self.passed,
        }


def _same_config(a: str, b: str) -> bool:
    if a == b:
        return True
    if os.path.isfile(a) and os.path.isfile(b):
        with open(a, "rb") as fa, open(b, "rb") as fb:
            return fa.read() == fb.read()
    return False


def _verdict(m: MetricComparison, p: float, alpha: float) -> str:
    if p >= alpha or m.difference == 0:
        return NO_DIFFERENCE
    return BETTER if m.regression < 0 else WORSE


def _describe_ids(ids: np.ndarray, limit: int = 3) -> str:
    shown = ", ".join(str(i) for i in ids[:limit])
    return shown + (f", ... ({ids.size} in all)" if ids.size > limit else "")


def compare_results(
    base: ScoringResult,
    new: ScoringResult,
    metrics: list[str] | None = None,
    gates: list[Gate] | None = None,
    settings: PairedSettings | None = None,
    min_shared: int = 1,
    only_significant: bool = False,
) -> Comparison:
    """Compares `new` against `base` on the scenarios both contain.

    Args:
      metrics: metric names (aliases accepted, comma-separated lists too) to
        report; None for all. Gated metrics are always included.
      gates: regressions to fail on.
      settings: the paired tests' settings (`stats.PairedSettings`: alpha, adjust, seed, n_boot,
        n_perm); None: the defaults.
      min_shared: fewer shared scenarios than this is an error.
      only_significant: a gate fails only when its regression is also significant.

    Raises:
      CompareError: no (or too few) shared scenarios, unknown metric, results of different challenges.
    """
    settings = PairedSettings() if settings is None else settings
    gates = list(gates or [])
    wanted = _wanted_metrics(metrics, gates)
    if base.challenge != new.challenge:
        raise CompareError(
            f"{base.path} is a {base.challenge} result and {new.path} a {new.challenge} result: "
            f"results of different challenges measure different things and cannot be compared"
        )
    warnings: list[str] = []
    if not _same_config(base.config, new.config):
        warnings.append(
            f"the results were scored with different configs: base {base.config!r}, "
            f"new {new.config!r}; differences mix the simulator change with the config change"
        )
    shared = _shared_scenarios(base, new, min_shared, warnings)
    results, exact = _paired_metrics(base, new, shared, wanted, settings)
    _unpaired_metrics(base, new, wanted, results, shared.sets_differ, warnings)
    return Comparison(
        base_path=base.path,
        new_path=new.path,
        base_config=base.config,
        new_config=new.config,
        challenge=new.challenge,
        num_shared=int(shared.base_rows.size),
        num_base_only=int(shared.base_only.size),
        num_new_only=int(shared.new_only.size),
        alpha=settings.alpha,
        adjust=settings.adjust,
        seed=settings.seed,
        n_boot=settings.n_boot,
        n_perm=settings.n_perm,
        exact_permutation=exact,
        metrics=[results[m] for m in wanted if m in results],
        gates=[_apply_gate(g, results.get(g.metric), only_significant) for g in gates],
        warnings=warnings,
    )


def _wanted_metrics(metrics: list[str] | None, gates: list[Gate]) -> list[str]:
    """The metrics asked for ("--metric a,b" or repeated; all when none), and the gated ones, in display order."""
    names = [n for m in metrics or [] for n in m.split(",") if n.strip()]
    wanted = [canonical_metric(n) for n in names] if names else list(METRICS)
    wanted += [g.metric for g in gates if g.metric not in wanted]
    return [m for m in METRICS if m in wanted]  # display order, no duplicates


@dataclasses.dataclass(frozen=True)
class _Shared:
    """The rows of the scenarios both results hold (paired, `result_reader.shared_rows`), and the rows of
    each result's own."""

    base_rows: np.ndarray
    new_rows: np.ndarray
    base_only: np.ndarray
    new_only: np.ndarray

    @property
    def sets_differ(self) -> bool:
        return bool(self.base_only.size or self.new_only.size)


def _shared_scenarios(base: ScoringResult, new: ScoringResult, min_shared: int, warnings: list[str]) -> _Shared:
    """The scenarios the comparison pairs; CompareError when there are too few, a warning when the sets or
    the skipped scenarios differ, or the pairs are few."""
    base_rows, new_rows = shared_rows(base, new)
    n = int(base_rows.size)
    base_only = np.setdiff1d(np.arange(base.num_scenarios), base_rows)
    new_only = np.setdiff1d(np.arange(new.num_scenarios), new_rows)
    if n == 0:
        raise CompareError(
            f"{base.path} ({base.num_scenarios} scenarios) and {new.path} ({new.num_scenarios} "
            f"scenarios) share no scenario: they were scored on different data sets"
        )
    if n < min_shared:
        raise CompareError(f"{base.path} and {new.path} share only {n} scenarios, fewer than --min-shared {min_shared}")
    if base_only.size or new_only.size:
        parts = []
        if base_only.size:
            parts.append(f"{base_only.size} only in base ({_describe_ids(base.scenario_ids[base_only])})")
        if new_only.size:
            parts.append(f"{new_only.size} only in new ({_describe_ids(new.scenario_ids[new_only])})")
        warnings.append(f"the scenario sets differ: compared on the {n} shared scenarios; " + "; ".join(parts))
    if n < FEW_SCENARIOS:
        warnings.append(f"only {n} shared scenarios: confidence intervals and p-values are rough")
    skipped_base = {s.get("scenario_id") for s in base.skipped}
    skipped_new = {s.get("scenario_id") for s in new.skipped}
    if skipped_base != skipped_new:
        warnings.append(
            f"the scorer skipped different scenarios: {len(skipped_base)} in base, {len(skipped_new)} in new"
        )
    return _Shared(base_rows, new_rows, base_only, new_only)


def _paired_metrics(
    base: ScoringResult, new: ScoringResult, shared: _Shared, wanted: list[str], settings: PairedSettings
) -> tuple[dict[str, MetricComparison], bool]:
    """The metrics both results have per scenario, compared scenario by scenario (all metrics resampled
    with the same draws), with their verdicts; and whether the permutation test was exact."""
    paired = [m for m in wanted if base.has_per_scenario(m) and new.has_per_scenario(m)]
    results: dict[str, MetricComparison] = {}
    if not paired:
        return results, False
    b = np.stack([base.per_scenario(m)[shared.base_rows] for m in paired], axis=1)  # (shared, metrics)
    w = np.stack([new.per_scenario(m)[shared.new_rows] for m in paired], axis=1)
    test = settings.test(b, w)
    for j, m in enumerate(paired):
        results[m] = MetricComparison(
            metric=m,
            higher_is_better=higher_is_better(m),
            paired=True,
            base=float(b[:, j].mean()),
            new=float(w[:, j].mean()),
            difference=float(test.mean_difference[j]),
            ci_low=float(test.ci_low[j]),
            ci_high=float(test.ci_high[j]),
            p_value=float(test.p_value[j]),
        )
    holm = stats.holm_adjust(test.p_value)
    for j, m in enumerate(paired):
        p_holm = results[m].p_holm = float(holm[j])
        p = p_holm if settings.adjust == "holm" else float(test.p_value[j])
        results[m].verdict = _verdict(results[m], p, settings.alpha)
    return results, test.exact_permutation


def _unpaired_metrics(
    base: ScoringResult,
    new: ScoringResult,
    wanted: list[str],
    results: dict[str, MetricComparison],
    sets_differ: bool,
    warnings: list[str],
) -> None:
    """Add to `results` the metrics the results have only as file aggregates (no interval, no p-value),
    saying so in `warnings`; a metric neither has is left out, with a warning."""
    unpaired = [m for m in wanted if m not in results]
    for m in unpaired:
        bv, nv = base.headline(m), new.headline(m)
        if bv is None or nv is None:
            warnings.append(f"{m}: not in both results, left out")
            continue
        results[m] = MetricComparison(
            metric=m, higher_is_better=higher_is_better(m), paired=False, base=bv, new=nv, difference=nv - bv
        )
    if any(m in results for m in unpaired):
        aggregated = ", ".join(m for m in unpaired if m in results)
        scope = "all of each file's scenarios" if not sets_differ else "each file's own scenarios (the sets differ!)"
        warnings.append(
            f"no per-scenario values for {aggregated}: compared the files' aggregates over {scope}, "
            f"without interval or p-value"
        )


def _apply_gate(gate: Gate, m: MetricComparison | None, only_significant: bool) -> GateOutcome:
    if m is None:
        return GateOutcome(gate, None, False, f"{gate.metric} is not in both results, cannot check the gate")
    regression = m.regression
    allowed = gate.allowed(m.base)
    too_much = regression > allowed
    if too_much and only_significant and m.paired and m.verdict != WORSE:
        return GateOutcome(
            gate,
            regression,
            True,
            f"worse by {regression:.6g} > allowed {allowed:.6g}, but not significant "
            f"(p={m.p_value:.4g}); passing because of --only-significant",
            allowed,
        )
    if too_much:
        return GateOutcome(gate, regression, False, f"worse by {regression:.6g} > allowed {allowed:.6g}", allowed)
    if regression > 0:
        return GateOutcome(gate, regression, True, f"worse by {regression:.6g} <= allowed {allowed:.6g}", allowed)
    return GateOutcome(gate, regression, True, f"not worse (change {m.difference:+.6g})", allowed)
