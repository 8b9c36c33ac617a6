"""Golden cases: submissions scored by the official implementation, with its outputs.

Two collections: `../shared/golden` (real WOMD scenarios, every config; absent
in a user's clone) and `tests/data/oracle` (synthetic edge-case scenes, in the
repository, so they run everywhere). A case is `<scenario_id>__<policy>` with a
submission, the official metrics (`.json`) and the official features (`.features.npz`).
"""
from __future__ import annotations

import gzip
from functools import lru_cache
from pathlib import Path

from support.paths import SHARED, TEST_DATA
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.metrics.config import load_config
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import sim_agents_submission_pb2

GOLDEN = SHARED / "golden"
ORACLE = TEST_DATA / "oracle"
# Per-step features compared bit for bit (ADE is compared within 1e-6: float32 summation order).
EXACT_FEATURES = (
    "object_id", "object_type", "valid", "linear_speed", "linear_acceleration", "angular_speed",
    "angular_acceleration", "distance_to_nearest_object", "collision_per_step", "time_to_collision",
    "distance_to_road_edge", "offroad_per_step", "traffic_light_violation_per_step",
)
GOLDEN_CONFIGS = {
    "2025": "2025", "2024": "2024", "2023": "2023",
    "test": "official-configs/test_config.textproto",
    "test_dependent": "official-configs/test_config_dependent_timesteps.textproto",
}
ORACLE_CONFIGS = ("2025", "2024", "2023")


def case_names(folder: Path) -> list[str]:
    return sorted(p.name[: -len(".json")] for p in folder.glob("*.json")) if folder.is_dir() else []


GOLDEN_CASES = case_names(GOLDEN) or ["(no ../shared)"]
ORACLE_CASES = case_names(ORACLE)


@lru_cache(maxsize=None)
def scenarios_in(folder: Path) -> dict:
    return {s.scenario_id: s for s, _ in iter_scenarios(folder)}


def _rollouts(path: Path):
    raw = path.read_bytes()
    if path.suffix == ".gz":
        raw = gzip.decompress(raw)
    return sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw).scenario_rollouts[0]


@lru_cache(maxsize=None)
def golden_inputs(case: str):
    """(ScenarioArrays, RolloutArrays) of a `../shared/golden` case."""
    rollouts = _rollouts(GOLDEN / f"{case}.binproto")
    return scenario_arrays(scenarios_in(SHARED / "womd")[rollouts.scenario_id]), rollout_arrays(rollouts)


@lru_cache(maxsize=None)
def oracle_inputs(case: str):
    """(ScenarioArrays, RolloutArrays) of a `tests/data/oracle` case."""
    rollouts = _rollouts(ORACLE / f"{case}.binproto.gz")
    return scenario_arrays(scenarios_in(ORACLE / "scenes")[rollouts.scenario_id]), rollout_arrays(rollouts)


def golden_config(name: str):
    value = GOLDEN_CONFIGS[name]
    return load_config(value if value in ("2025", "2024", "2023") else SHARED / value)
