"""wosac-eval: exact WOSAC realism metrics without TensorFlow.

Public API (imported lazily, so `import wosac_eval.<module>` stays light):

  Scoring
    score_scenario(scenario, rollouts, config=None, challenge="sim_agents") -> dict of SimAgentMetrics fields
    score_scenario_per_object(scenario, rollouts, ...) -> PerObjectMetrics (the fields per object, events per rollout)
    score_submission(scenario_paths, submission_path, config=None, ...) -> result.json dict
    validate_submission(scenario_paths, submission_path) -> ValidationReport
    load_config("2025" | "2024" | "2023" | "scenario_gen_2025" | path.textproto) -> SimAgentMetricsConfig
    Challenge: SIM_AGENTS, SCENARIO_GEN
  Arrays in
    read_scenarios(paths) -> iterator of Scenario messages
    sim_agent_ids(scenario) -> int64 `(num_objects,)`: the objects to simulate
    rollouts_from_arrays(scenario_id, object_id, x, y, z, heading, *, length, width, height, object_type)
        -> RolloutArrays, scored as they are by score_scenario
    rollouts_message(rollouts) -> ScenarioRollouts; joint_scene(object_id, x, y, z, heading) -> JointScene
    SubmissionWriter(SubmissionMetadata(...), "out.tar.gz"): .add(rollouts) per scenario
  The official module layout: wosac_eval.compat.{metrics, submission_specs, converters}
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.3.0"
_API = {
    "InvalidSubmissionError": "wosac_eval.scoring.submission",
    "score_scenario": "wosac_eval.scoring.scenario",
    "score_scenario_per_object": "wosac_eval.scoring.scenario",
    "score_submission": "wosac_eval.scoring.submission",
    "Challenge": "wosac_eval.challenges",
    "sim_agent_ids": "wosac_eval.challenges",
    "load_config": "wosac_eval.metrics.config",
    "validate_submission": "wosac_eval.validate",
    "read_scenarios": "wosac_eval.parse.scenarios",
    "RolloutArrays": "wosac_eval.arrays.rollouts",
    "rollouts_from_arrays": "wosac_eval.arrays.messages",
    "rollouts_message": "wosac_eval.arrays.messages",
    "joint_scene": "wosac_eval.arrays.messages",
    "SubmissionMetadata": "wosac_eval.arrays.submission_writer",
    "SubmissionWriter": "wosac_eval.arrays.submission_writer",
}
__all__ = sorted(_API)


def __getattr__(name: str) -> Any:
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'wosac_eval' has no attribute {name!r}")
