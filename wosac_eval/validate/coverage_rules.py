"""Coverage rules: the scenarios a submission holds against the scenario set it is judged on.

Every scenario of the set must be submitted once, under its id, and nothing else: missing, unknown,
duplicate and unnamed scenarios are each a finding, and a submission none of whose scenarios is in the
set gets one more saying it was likely made for another split.
"""

from __future__ import annotations

from collections.abc import Iterable

from wosac_eval.validate.findings import Finding, Location, make_finding


def check_missing_scenarios(expected: Iterable[str], submitted: Iterable[str] | set[str]) -> list[Finding]:
    """One finding per scenario of the scenario set that the submission lacks (in scenario-set order)."""
    submitted = submitted if isinstance(submitted, (set, dict, frozenset)) else set(submitted)
    missing = [sid for sid in expected if sid not in submitted]
    total = len(missing)
    return [
        make_finding(
            "coverage.missing_scenario",
            f"missing from the submission ({total} scenario(s) of the set are missing)",
            Location(scenario_id=sid),
        )
        for sid in missing
    ]


def check_overlap(expected_count: int, submitted_ids: Iterable[str], expected: dict | set) -> list[Finding]:
    """One finding when scenarios were submitted but none is in the scenario set: likely the wrong split."""
    submitted = list(submitted_ids)
    if not submitted or not expected_count or any(sid in expected for sid in submitted):
        return []
    return [
        make_finding(
            "coverage.no_overlap",
            f"none of the {len(submitted)} submitted scenario(s) is in the scenario set of {expected_count} "
            f"(e.g. {submitted[0]}); are --scenarios the split the submission was made for "
            "(validation vs testing)?",
        )
    ]


def unknown_scenario(scenario_id: str, shard: str, index: int) -> Finding:
    return make_finding(
        "coverage.unknown_scenario",
        f"not in the scenario set (scenario_rollouts[{index}])",
        Location(shard, scenario_id),
    )


def duplicate_scenario(scenario_id: str, shard: str, index: int, first: tuple[str, int]) -> Finding:
    return make_finding(
        "coverage.duplicate_scenario",
        f"submitted again at scenario_rollouts[{index}]; first in {first[0]} at scenario_rollouts[{first[1]}]",
        Location(shard, scenario_id),
    )


def missing_scenario_id(shard: str, index: int) -> Finding:
    return make_finding(
        "coverage.missing_scenario_id",
        f"scenario_rollouts[{index}] has no scenario_id; its rollouts cannot be matched to a scenario",
        Location(shard),
    )
