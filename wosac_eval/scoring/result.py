"""The result document of a scored submission (what `wosac-eval score --output` writes).

    {"schema_version": 2, "challenge": "sim_agents", "config": "2025", "num_scenarios": N,
     "scenarios": [{"scenario_id": ..., <SimAgentMetrics fields>}, ...],
     "aggregate": {<every field, mean over scenarios>},
     "buckets": {<SimAgentsBucketedMetrics fields>},
     "skipped": [{"scenario_id": ..., "reason": ...}],
     "validation": {"errors": E, "warnings": W,
                    "findings": [{"code": ..., "severity": ..., "count": ..., "title": ..., "first": ...}]},
     "coverage": {"scored": N, "expected": M, "fraction": N / M},
     "analysis": {"criticality": {...}, "driving": {...}, "by_object_type": {...}}}

Each scenario row also carries `criticality` ({score, components, raw,
peak_step}), `driving` ({score, components}, or null) and `by_object_type`
({vehicle|pedestrian|cyclist: metrics}); `analysis` summarises them over the
scored scenarios. They are wosac-eval's diagnostics, beside the official
metrics (which they do not change).

`schema_version` is the document's layout (`result_reader.SCHEMA_VERSION`): 1 is
the documents written before the field (the same layout, without it), 2 records
it. A change a reader of earlier documents must know of (a new per-scenario
field, a renamed one) makes a new version (an entry of
`result_reader.VERSION_FIELDS`), and the reader keeps reading the earlier ones.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.analysis.criticality_scores import LONG_TAIL_QUANTILE, BehaviourHistogram, set_histogram, with_rarity
from wosac_eval.arrays.object_types import ANALYSED_TYPES
from wosac_eval.metrics.config import SimAgentMetricsConfig
from wosac_eval.metrics.scenario_metrics import aggregate_metrics, bucket_metrics
from wosac_eval.scoring.result_reader import SCHEMA_VERSION  # the newest layout, beside every earlier one's

if TYPE_CHECKING:  # the report `submission` passes in; importing it here would load the validation room
    from wosac_eval.validate.findings import ValidationReport


def summarize(config: SimAgentMetricsConfig, per_scenario: list[dict]) -> dict:
    """Aggregate (mean over scenarios) and bucketed metrics of scored scenarios."""
    aggregate = aggregate_metrics(per_scenario)
    return {"aggregate": aggregate, "buckets": bucket_metrics(config, aggregate)}


def _mean(values: Iterable[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def finish_analysis(per_scenario: list[dict], histogram: BehaviourHistogram | None = None) -> dict:
    """Completes every row's criticality with its rarity, and summarises the analyses.

    Rarity is rated against `histogram` (a `BehaviourHistogram`; default: that of the scored set).
    Rows scored without analysis are left as they are (and the summary is empty).
    """
    rows = [r for r in per_scenario if "criticality" in r]
    if not rows:
        return {}
    histogram = histogram or set_histogram([r["criticality"] for r in rows])
    for row in rows:
        row["criticality"] = with_rarity(row["criticality"], histogram)
    scores = np.array([r["criticality"]["score"] for r in rows])
    driving = [r["driving"] for r in rows if r.get("driving")]
    summary: dict[str, Any] = {
        "criticality": {
            "mean": float(scores.mean()),
            "long_tail_threshold": float(np.quantile(scores, LONG_TAIL_QUANTILE)),
            "behaviour_samples": int(histogram.counts.sum()),
        },
        "driving": None
        if not driving
        else {
            "num_scenarios": len(driving),
            "score": _mean(d["score"] for d in driving),
            "components": {k: _mean(d["components"][k] for d in driving) for k in driving[0]["components"]},
        },
        "by_object_type": {},
    }
    for kind in ANALYSED_TYPES:
        present = [r["by_object_type"][kind] for r in rows if kind in r.get("by_object_type", {})]
        if present:
            fields = [k for k in present[0] if k != "num_objects"]
            summary["by_object_type"][kind] = {
                "num_scenarios": len(present),
                "num_objects": sum(p["num_objects"] for p in present),
                **{k: _mean(p[k] for p in present) for k in fields},
            }
    return summary


def validation_summary(report: ValidationReport) -> dict:
    """Counts and, per finding code, its severity, count and first message: what was ignored or skipped."""
    groups = report.to_dict()["groups"]
    return {
        "errors": report.error_count,
        "warnings": report.warning_count,
        "findings": [
            {
                "code": g["code"],
                "severity": g["severity"],
                "count": g["count"],
                "title": g["title"],
                "first": g["listed"][0]["message"] if g["listed"] else "",
            }
            for g in groups
        ],
    }


def result_document(
    challenge: challenges.ChallengeLike,
    config_name: str,
    config: SimAgentMetricsConfig,
    per_scenario: list[dict],
    report: ValidationReport,
    *,
    selection: dict | None = None,
    selected: set | None = None,
    histogram: BehaviourHistogram | None = None,
) -> dict:
    """The result document of scored scenarios and the submission's validation report.

    With a `selection` ({"rule", "scenarios", "of", "min_criticality"}, from `score --select`) of the
    `selected` scenario ids, the coverage and the skipped scenarios count those only.
    """
    skipped = [{"scenario_id": sid, "reason": reason} for sid, reason in sorted(report.skipped_scenarios.items())]
    expected = report.stats.scenarios_expected
    if selection is not None:
        assert selected is not None  # given with `selection`
        skipped = [s for s in skipped if s["scenario_id"] in selected]
        expected = selection["scenarios"]
    analysis = finish_analysis(per_scenario, histogram)
    return {
        "schema_version": SCHEMA_VERSION,
        "challenge": challenges.as_challenge(challenge).value,
        "config": config_name,
        "num_scenarios": len(per_scenario),
        "scenarios": per_scenario,
        **summarize(config, per_scenario),
        "skipped": skipped,
        "validation": validation_summary(report),
        "coverage": {
            "scored": len(per_scenario),
            "expected": expected,
            "fraction": len(per_scenario) / expected if expected else 0.0,
        },
        **({"analysis": analysis} if analysis else {}),
        **({"selection": selection} if selection is not None else {}),
    }
