"""Submission validation: every problem of a submission, located precisely, before scoring or upload."""

from wosac_eval.validate.findings import CODES, Finding, ValidationReport
from wosac_eval.validate.validator import (
    ScenarioSetError,
    load_sim_agents,
    validate_scenario_rollouts,
    validate_submission,
)

__all__ = [
    "CODES",
    "Finding",
    "ScenarioSetError",
    "ValidationReport",
    "load_sim_agents",
    "validate_scenario_rollouts",
    "validate_submission",
]
