"""Synthetic result documents shaped like the service's (for the results tests and the streaming
benchmark): rows of ~3.2 kB with the fields, nesting, nulls and NaNs of real per-scenario rows, so
that 44,097 of them make a document of about the size of a validation-set result (~140 MB)."""

from __future__ import annotations

import random

from wosac_eval.analysis import criticality_scores, driving_scores
from wosac_eval.metrics.registry import LIKELIHOOD_FIELDS, RATE_FIELDS

# The fields of real rows, from where the scoring code declares them.
METRICS = list(LIKELIHOOD_FIELDS)
RATES = list(RATE_FIELDS)
CRITICALITY = list(criticality_scores.COMPONENTS)
DRIVING = list(driving_scores.COMPONENTS)


def synthetic_row(i: int, rng: random.Random) -> dict:
    u = rng.random
    row = {
        "scenario_id": f"{i:016x}",
        "metametric": u(),
        "average_displacement_error": 10 * u(),
        "min_average_displacement_error": 5 * u(),
        **{m: u() for m in METRICS},
        **{r: u() for r in RATES},
        "criticality": {
            "score": u(),
            "components": {c: u() for c in CRITICALITY},
            "raw": {c: 20 * u() - 5 for c in CRITICALITY},
            "peak_step": rng.randrange(91),
        },
        "driving": None if i % 11 == 5 else {"score": u(), "components": {d: u() for d in DRIVING}},
        "by_object_type": {
            kind: {
                "num_objects": rng.randrange(1, 40),
                **{m: (None if kind != "vehicle" and m == "time_to_collision_likelihood" else u()) for m in METRICS},
                "metametric": u(),
                "min_average_displacement_error": u(),
                **{r: u() for r in RATES},
            }
            for kind, share in (("vehicle", 1.0), ("pedestrian", 0.7), ("cyclist", 0.2))
            if u() < share
        },
    }
    if i % 97 == 3:
        row["min_average_displacement_error"] = float("nan")  # stored and served as NaN, as json.dump writes it
    return row


def synthetic_result(n: int, seed: int = 0) -> dict:
    """A result document of `n` rows in the key order of `wosac_eval.scoring.result.result_document`.

    Row 1 carries a field no other row has, and `driving` is null in some rows and an object in others,
    and a scalar in row 2: the CSV's columns are every field with a scalar value in some row."""
    rng = random.Random(seed)
    rows = [synthetic_row(i, rng) for i in range(n)]
    if n > 2:
        rows[1]["note"] = 'a "quoted", comma'
        rows[2]["driving"] = 0.5
    aggregate = {"metametric": 0.6, **{m: 0.5 for m in METRICS}}
    return {
        "challenge": "sim_agents",
        "config": "2025",
        "num_scenarios": n,
        "scenarios": rows,
        "aggregate": aggregate,
        "buckets": {
            "realism_meta_metric": 0.6,
            "kinematic_metrics": 0.5,
            "interactive_metrics": 0.7,
            "map_based_metrics": 0.8,
            "min_ade": 1.25,
        },
        "skipped": [],
        "validation": {"errors": 0, "warnings": 0, "findings": []},
        "coverage": {"scored": n, "expected": n, "fraction": 1.0},
        "analysis": {"criticality": {"mean": 0.5, "long_tail_threshold": 0.9, "behaviour_samples": 7 * n}},
    }
