"""wosac-eval: exact WOSAC realism metrics without TensorFlow.

Public API:
  score_scenario(scenario, rollouts, config="2025") -> dict of SimAgentMetrics fields
  score_submission(scenario_paths, submission_path, config="2025", ...) -> result.json dict
  load_config("2025" | "2024" | "2023" | path.textproto) -> SimAgentMetricsConfig
  validate_submission(scenario_paths, submission_path) -> ValidationReport
"""
from wosac_eval.metrics.config import load_config
from wosac_eval.metrics.submission import InvalidSubmissionError, score_scenario, score_submission
from wosac_eval.validate import validate_submission

__all__ = ["InvalidSubmissionError", "load_config", "score_scenario", "score_submission",
           "validate_submission"]
__version__ = "0.1.0"
