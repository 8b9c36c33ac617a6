"""The result document of a scored submission (what `wosac-eval score --output` writes).

    {"challenge": "sim_agents", "config": "2025", "num_scenarios": N,
     "scenarios": [{"scenario_id": ..., <SimAgentMetrics fields>}, ...],
     "aggregate": {<every field, mean over scenarios>},
     "buckets": {<SimAgentsBucketedMetrics fields>},
     "skipped": [{"scenario_id": ..., "reason": ...}],
     "validation": {"errors": E, "warnings": W,
                    "findings": [{"code": ..., "severity": ..., "count": ..., "title": ..., "first": ...}]},
     "coverage": {"scored": N, "expected": M, "fraction": N / M}}
"""
from __future__ import annotations

from wosac_eval import challenges
from wosac_eval.metrics.config import SimAgentMetricsConfig
from wosac_eval.metrics.scenario_metrics import aggregate_metrics, bucket_metrics


def summarize(config: SimAgentMetricsConfig, per_scenario: list[dict]) -> dict:
    """Aggregate (mean over scenarios) and bucketed metrics of scored scenarios."""
    aggregate = aggregate_metrics(per_scenario)
    return {"aggregate": aggregate, "buckets": bucket_metrics(config, aggregate)}


def validation_summary(report) -> dict:
    """Counts and, per finding code, its severity, count and first message: what was ignored or skipped."""
    groups = report.to_dict()["groups"]
    return {"errors": report.error_count, "warnings": report.warning_count,
            "findings": [{"code": g["code"], "severity": g["severity"], "count": g["count"], "title": g["title"],
                          "first": g["listed"][0]["message"] if g["listed"] else ""} for g in groups]}


def result_document(challenge, config_name: str, config: SimAgentMetricsConfig, per_scenario: list[dict],
                    report) -> dict:
    """The result document of scored scenarios and the submission's validation report."""
    skipped = [{"scenario_id": sid, "reason": reason} for sid, reason in sorted(report.skipped_scenarios.items())]
    expected = report.stats.scenarios_expected
    return {"challenge": challenges.as_challenge(challenge).value, "config": config_name,
            "num_scenarios": len(per_scenario), "scenarios": per_scenario, **summarize(config, per_scenario),
            "skipped": skipped,
            "validation": validation_summary(report),
            "coverage": {"scored": len(per_scenario), "expected": expected,
                         "fraction": len(per_scenario) / expected if expected else 0.0}}
