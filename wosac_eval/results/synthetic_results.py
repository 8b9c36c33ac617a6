"""Synthetic `score` results with known differences, for tests, benchmarks and demo reports.

The values look like real WOSAC results (likelihoods in (0, 1) that move
together with a per-scenario difficulty, small collision / offroad rates,
displacement errors in metres) but are drawn from numpy, so a test knows the
true difference between two runs: a run made with `shift` differs from the run
made with the same seed by exactly that shift on every scenario (plus `jitter`
noise when asked).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from wosac_eval.metrics.config import preset
from wosac_eval.metrics.registry import BUCKET_MEMBERS, LIKELIHOOD_FIELDS, METRIC_NAMES, RATE_FIELDS
from wosac_eval.scoring.result_reader import SCHEMA_VERSION

# 2025 challenge metametric weights, by config field.
# (float32 in the config message; the decimal weights here)
WEIGHTS_2025: dict[str, float] = {m: float(f"{getattr(preset('2025'), m).metametric_weight:.7g}") for m in METRIC_NAMES}
LIKELIHOODS = LIKELIHOOD_FIELDS


def synthetic_scenarios(
    num_scenarios: int,
    seed: int,
    shift: dict[str, float] | None = None,
    jitter: float = 0.0,
    jitter_seed: int = 1,
    id_prefix: str = "scn",
) -> list[dict[str, Any]]:
    """Per-scenario result entries.

    Args:
      num_scenarios: how many scenarios (ids `{id_prefix}{index:06d}`).
      seed: draws the scenarios; the same seed gives the same base values.
      shift: field -> constant added on every scenario. Likelihood shifts carry
        into the metametric (with the 2025 weights); rate and ADE shifts are
        added to those fields.
      jitter: standard deviation of independent noise added to each likelihood
        (and a quarter of it to the collision and offroad rates): a run that
        differs by more than a constant.
      jitter_seed: seeds that noise.
    """
    shift = dict(shift or {})
    rng = np.random.default_rng(seed)
    n = num_scenarios
    difficulty = rng.beta(4.0, 2.5, size=n)  # (num_scenarios,) shared by all metrics of a scenario
    values: dict[str, np.ndarray] = {}
    for k, field in enumerate(LIKELIHOODS):
        level = 0.35 + 0.1 * (k % 4)
        # Kept inside [0.02, 0.95] so that a small shift never has to be clipped.
        values[field] = np.clip(level + 0.5 * (difficulty - 0.6) + rng.normal(0.0, 0.05, n), 0.02, 0.95)
    # Rates and errors come from the unshifted draws, so a shift changes only the fields it names.
    values["average_displacement_error"] = rng.gamma(2.0, 1.5, n) * (1.5 - difficulty)
    values["min_average_displacement_error"] = values["average_displacement_error"] * rng.uniform(0.4, 0.8, n)
    values["simulated_collision_rate"] = np.clip(
        0.25 * (1 - values["collision_indication_likelihood"]) + rng.normal(0, 0.02, n), 0.0, 1.0
    )
    values["simulated_offroad_rate"] = np.clip(
        0.2 * (1 - values["offroad_indication_likelihood"]) + rng.normal(0, 0.02, n), 0.0, 1.0
    )
    values["simulated_traffic_light_violation_rate"] = rng.binomial(1, 0.03, n) * rng.uniform(0.0, 0.5, n)
    if jitter:
        noise = np.random.default_rng(jitter_seed)
        for field in LIKELIHOODS:
            values[field] = np.clip(values[field] + noise.normal(0.0, jitter, n), 0.0, 1.0)
        for field in RATE_FIELDS[:2]:
            values[field] = np.clip(values[field] + noise.normal(0.0, jitter / 4, n), 0.0, 1.0)
    for field in LIKELIHOODS:
        values[field] = values[field] + shift.pop(field, 0.0)
    values["metametric"] = np.asarray(sum(WEIGHTS_2025[f.removesuffix("_likelihood")] * values[f] for f in LIKELIHOODS))
    for field in (*RATE_FIELDS, "average_displacement_error", "min_average_displacement_error", "metametric"):
        values[field] = values[field] + shift.pop(field, 0.0)
    if shift:
        raise ValueError(f"cannot shift unknown fields {sorted(shift)}")
    return [{"scenario_id": f"{id_prefix}{i:06d}", **{f: float(v[i]) for f, v in values.items()}} for i in range(n)]


def result_json(
    scenarios: list[dict[str, Any]], config: str = "2025", skipped: list[dict[str, Any]] | None = None
) -> dict[str, Any]:
    """A complete result JSON (aggregate and buckets computed) around per-scenario entries."""
    fields = [k for k in scenarios[0] if k != "scenario_id"] if scenarios else []
    aggregate = {f: float(np.mean([s[f] for s in scenarios])) for f in fields}
    buckets = {"realism_meta_metric": aggregate.get("metametric", 0.0)}
    for bucket, members in BUCKET_MEMBERS.items():
        w = np.array([WEIGHTS_2025[m] for m in members])
        buckets[bucket] = float(np.dot([aggregate.get(f"{m}_likelihood", 0.0) for m in members], w) / w.sum())
    buckets["min_ade"] = aggregate.get("min_average_displacement_error", 0.0)
    for rate in RATE_FIELDS:
        buckets[rate] = aggregate.get(rate, 0.0)
    return {
        "schema_version": SCHEMA_VERSION,
        "challenge": "sim_agents",
        "config": config,
        "scenarios": scenarios,
        "aggregate": aggregate,
        "buckets": buckets,
        "skipped": list(skipped or []),
    }


def synthetic_result(num_scenarios: int, seed: int, config: str = "2025", **kwargs: Any) -> dict[str, Any]:
    """`result_json(synthetic_scenarios(...))`: a whole synthetic result."""
    return result_json(synthetic_scenarios(num_scenarios, seed, **kwargs), config=config)


GATE_DEMO_TITLE = "WOSAC realism: my-sim (PR) vs baseline (main)"


def write_gate_demo_results(folder: str | os.PathLike[str], num_scenarios: int = 2000) -> tuple[Path, Path]:
    """Writes `folder`/baseline.json and `folder`/new.json and returns their paths.

    Synthetic results of `num_scenarios` scenarios: in the new run the
    collision likelihood and rate improve, the offroad likelihood gets worse,
    and 10 scenarios were skipped (for trying `compare` / `report`).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    base = synthetic_scenarios(num_scenarios, seed=0)
    new = synthetic_scenarios(
        num_scenarios,
        seed=0,
        jitter=0.02,
        jitter_seed=7,
        shift={
            "collision_indication_likelihood": 0.012,
            "offroad_indication_likelihood": -0.006,
            "simulated_collision_rate": -0.004,
        },
    )
    kept = num_scenarios - 10
    skipped = [
        {"scenario_id": s["scenario_id"], "reason": "no rollouts in the submission (scored with --partial)"}
        for s in new[kept:]
    ]
    base_path, new_path = folder / "baseline.json", folder / "new.json"
    base_path.write_text(json.dumps(result_json(base)))
    new_path.write_text(json.dumps(result_json(new[:kept], skipped=skipped)))
    return base_path, new_path
