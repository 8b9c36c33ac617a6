"""Submission validation: every problem of a submission, located precisely, before scoring or upload."""

from wosac_eval.validate.findings import CODES, Finding, ValidationReport
from wosac_eval.validate.scenario_set import ScenarioSetError, load_sim_agents
from wosac_eval.validate.shard_checks import validate_scenario_rollouts
from wosac_eval.validate.validator import ValidationOptions, validate_submission

__all__ = [
    "CODES",
    "Finding",
    "ScenarioSetError",
    "ValidationOptions",
    "ValidationReport",
    "load_sim_agents",
    "validate_scenario_rollouts",
    "validate_submission",
]
