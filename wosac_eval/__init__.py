"""wosac-eval: exact WOSAC realism metrics without TensorFlow.

Public API (imported lazily, so `import wosac_eval.<module>` stays light):
  score_scenario(scenario, rollouts, config="2025") -> dict of SimAgentMetrics fields
  score_submission(scenario_paths, submission_path, config="2025", ...) -> result.json dict
  load_config("2025" | "2024" | "2023" | path.textproto) -> SimAgentMetricsConfig
  validate_submission(scenario_paths, submission_path) -> ValidationReport
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"
_API = {
    "InvalidSubmissionError": "wosac_eval.scoring.submission",
    "score_scenario": "wosac_eval.scoring.scenario",
    "score_submission": "wosac_eval.scoring.submission",
    "Challenge": "wosac_eval.challenges",
    "load_config": "wosac_eval.metrics.config",
    "validate_submission": "wosac_eval.validate",
}
__all__ = sorted(_API)


def __getattr__(name: str):
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'wosac_eval' has no attribute {name!r}")
