"""Findings (one per problem found in a submission) and the report that groups them.

A submission with a systematic fault (say every trajectory 79 steps long) can
produce millions of findings. The report therefore keeps, per finding code, a
count and only the first `max_listed` findings in full, so its memory is
bounded by the number of codes, not by the number of problems. What it keeps
per scenario (which scenarios are invalid, and why) is bounded by the size of
the scenario set, which the scorer needs for partial scoring.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from wosac_eval.challenges import Challenge, ChallengeLike, as_challenge

ERROR = "error"
WARNING = "warning"

# Every finding code, with the title its group gets in the report. Codes are
# stable (tools may match on them); titles are for people.
CODES: dict[str, str] = {
    # The submission file or archive as a whole.
    "container.unreadable": "Submission file or archive cannot be read",
    "container.unsafe_member": "Archive member rejected as unsafe (escaping path, link or device)",
    "container.size_limit": "Submission expands past an input limit (size, ratio, members, messages)",
    "container.not_a_shard": "File in the submission folder that is not a shard",
    "container.misnamed": "File name does not match its format",
    "container.not_gzipped": "Uncompressed tar (the challenge server expects .tar.gz)",
    # One shard (one SimAgentsChallengeSubmission message).
    "shard.unparseable": "Shard is not a SimAgentsChallengeSubmission",
    "shard.empty": "Shard holds no scenario",
    # Submission metadata.
    "metadata.missing": "Required metadata field missing or empty",
    "metadata.invalid": "Metadata field has an invalid value",
    "metadata.inconsistent": "Metadata differs between shards",
    "metadata.recommended": "Recommended metadata field missing",
    # Scenario coverage against the scenario set.
    "coverage.no_overlap": "No submitted scenario is in the scenario set (wrong split?)",
    "coverage.missing_scenario": "Scenario of the scenario set missing from the submission",
    "coverage.unknown_scenario": "Scenario not in the scenario set",
    "coverage.duplicate_scenario": "Scenario submitted more than once",
    "coverage.missing_scenario_id": "ScenarioRollouts without a scenario_id",
    # Per scenario, per rollout (joint scene), per object.
    "rollouts.wrong_count": "Wrong number of joint scenes (rollouts)",
    "rollouts.missing_sim_agents": "Sim agents missing from a joint scene",
    "rollouts.extra_objects": "Objects that are not sim agents in a joint scene",
    "rollouts.duplicate_objects": "Object simulated more than once in a joint scene",
    "rollouts.missing_object_id": "Simulated trajectory without an object_id",
    "rollouts.wrong_length": "Trajectory field with the wrong number of values",
    "rollouts.non_finite": "Trajectory field with NaN or infinite values",
    "rollouts.non_positive_size": "Box size that is zero or negative (scenario gen; scored as given)",
    "rollouts.missing_object_type": "Simulated trajectory without an object_type (scenario gen; scored as TYPE_UNSET)",
    "rollouts.ignored_field": "Submitted field the challenge's evaluator ignores",
}


@dataclass(frozen=True)
class Finding:
    """One problem in a submission, located as precisely as it can be.

    `message` is a complete sentence that names its own location (shard,
    scenario, rollout, object, field) so it can be printed alone; the location
    fields repeat it in machine-readable form (None where it does not apply).
    `hint` is the likely cause and its fix, shared by many findings (e.g. "80
    values is a sim_agents submission: ..."): the report prints it once per
    group with a count, not on every line, so it is not part of `message`.
    """

    code: str
    message: str
    shard: str | None = None
    scenario_id: str | None = None
    rollout: int | None = None
    object_id: int | None = None
    field: str | None = None
    severity: str = ERROR
    hint: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """The finding as JSON-ready data; the hint is left to its group (`FindingGroup.hints`)."""
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None and k != "hint"}


def where(
    shard: str | None = None,
    scenario_id: str | None = None,
    rollout: int | None = None,
    object_id: int | None = None,
) -> str:
    """The location prefix of a message, e.g. 'shard-3.binproto: scenario ab12 rollout 3 object 7'.

    The field is not part of the prefix: every detail about a field names it
    itself ("field center_x has 79 values", "heading[17] is NaN").
    """
    parts = []
    if scenario_id is not None:
        parts.append(f"scenario {printable(scenario_id)}")
    if rollout is not None:
        parts.append(f"rollout {rollout}")
    if object_id is not None:
        parts.append(f"object {object_id}")
    text = " ".join(parts)
    if shard is not None:
        text = f"{printable(shard)}: {text}" if text else printable(shard)
    return text


def printable(name: str) -> str:
    """A name as is, or quoted with escapes when it holds newlines or other control characters.

    Scenario ids and member names come from the submission: they must not be
    able to forge extra lines in the report.
    """
    return name if name.isprintable() else repr(name)


@dataclass(frozen=True)
class Location:
    """Where a finding is: its shard, scenario, rollout (joint scene) and object; None where it does not
    apply. The field a finding is about is not part of it: `make_finding` takes it beside."""

    shard: str | None = None
    scenario_id: str | None = None
    rollout: int | None = None
    object_id: int | None = None


NOWHERE = Location()  # a finding about the submission as a whole


def make_finding(
    code: str,
    detail: str,
    location: Location = NOWHERE,
    *,
    field: str | None = None,
    severity: str = ERROR,
    hint: str | None = None,
) -> Finding:
    """A Finding whose message is '<location>: <detail>'."""
    if code not in CODES:
        raise KeyError(f"unknown finding code {code!r}")
    shard, scenario_id, rollout, object_id = location.shard, location.scenario_id, location.rollout, location.object_id
    loc = where(shard, scenario_id, rollout, object_id)
    message = f"{loc}: {detail}" if loc else detail
    return Finding(code, message, shard, scenario_id, rollout, object_id, field, severity, hint)


def format_ids(ids: Iterable[object], limit: int = 20) -> str:
    """'[1, 2, 3]' or '[1, 2, ... (+40 more)]' so one message stays one line."""
    ids = list(ids)
    shown = ", ".join(str(i) for i in ids[:limit])
    more = f", ... (+{len(ids) - limit} more)" if len(ids) > limit else ""
    return f"[{shown}{more}]"


@dataclass
class FindingGroup:
    """All findings of one code: how many, the first few in full, and each distinct hint with its count.

    Hints come from a small fixed set of causes, so `hints` stays small however
    many findings share one.
    """

    code: str
    severity: str
    count: int = 0
    listed: list[Finding] = field(default_factory=list)
    hints: dict[str, int] = field(default_factory=dict)

    @property
    def title(self) -> str:
        return CODES[self.code]

    def to_dict(self) -> dict[str, Any]:
        data = {
            "code": self.code,
            "title": self.title,
            "severity": self.severity,
            "count": self.count,
            "listed": [f.to_dict() for f in self.listed],
        }
        if self.hints:
            data["hints"] = [{"hint": hint, "count": count} for hint, count in self.hints.items()]
        return data


@dataclass
class ValidationStats:
    shards: int = 0
    scenarios_expected: int = 0
    scenarios_submitted: int = 0
    scenarios_valid: int = 0
    bytes_read: int = 0
    elapsed_s: float = 0.0

    @property
    def scenarios_per_s(self) -> float:
        return self.scenarios_submitted / self.elapsed_s if self.elapsed_s > 0 else 0.0


class ValidationReport:
    """Every finding of one validation run, grouped by code with counts.

    `ok` is True when no finding has severity 'error' (warnings do not make a
    submission invalid). `skipped_scenarios` maps each scenario of the scenario
    set that cannot be scored (missing, or with at least one error) to the first
    reason, so a partial scorer can list what it skipped.
    """

    def __init__(
        self, submission: str = "", max_listed: int = 20, challenge: ChallengeLike = Challenge.SIM_AGENTS
    ) -> None:
        if max_listed < 0:
            raise ValueError("max_listed must be >= 0")
        self.submission = submission
        self.challenge = as_challenge(challenge)
        self.max_listed = max_listed
        self.groups: dict[str, FindingGroup] = {}
        self.stats = ValidationStats()
        self.invalid_scenarios: dict[str, str] = {}
        self.missing_scenarios: list[str] = []

    # -- collecting -------------------------------------------------------
    def add(self, finding: Finding) -> None:
        group = self.groups.get(finding.code)
        if group is None:
            group = self.groups[finding.code] = FindingGroup(finding.code, finding.severity)
        group.count += 1
        if len(group.listed) < self.max_listed:
            group.listed.append(finding)
        if finding.hint is not None:
            group.hints[finding.hint] = group.hints.get(finding.hint, 0) + 1
        if finding.severity == ERROR and finding.scenario_id is not None:
            self.invalid_scenarios.setdefault(finding.scenario_id, finding.message)

    def extend(self, findings: Iterable[Finding]) -> None:
        for f in findings:
            self.add(f)

    def merge(self, other: ValidationReport) -> None:
        """Add another report's findings (counts, listed findings, invalid scenarios) after this one's."""
        for code, theirs in other.groups.items():
            group = self.groups.get(code)
            if group is None:
                group = self.groups[code] = FindingGroup(code, theirs.severity)
            group.count += theirs.count
            room = self.max_listed - len(group.listed)
            group.listed.extend(theirs.listed[: max(room, 0)])
            for hint, count in theirs.hints.items():
                group.hints[hint] = group.hints.get(hint, 0) + count
        for scenario_id, reason in other.invalid_scenarios.items():
            self.invalid_scenarios.setdefault(scenario_id, reason)

    # -- reading ----------------------------------------------------------
    @property
    def ok(self) -> bool:
        return self.error_count == 0

    @property
    def error_count(self) -> int:
        return sum(g.count for g in self.groups.values() if g.severity == ERROR)

    @property
    def metadata_error_count(self) -> int:
        """Errors of the submission's metadata (account, method, flags): no partial scoring goes past them."""
        return sum(g.count for code, g in self.groups.items() if g.severity == ERROR and code.startswith("metadata."))

    @property
    def warning_count(self) -> int:
        return sum(g.count for g in self.groups.values() if g.severity != ERROR)

    def count(self, code: str) -> int:
        group = self.groups.get(code)
        return group.count if group else 0

    def findings(self, code: str | None = None) -> list[Finding]:
        """The findings kept in full (the first max_listed of each code)."""
        groups = [self.groups[code]] if code in self.groups else [] if code else self.groups.values()
        return [f for g in groups for f in g.listed]

    @property
    def skipped_scenarios(self) -> dict[str, str]:
        """Scenario id -> reason, for every scenario that a partial scorer must skip."""
        skipped = dict.fromkeys(self.missing_scenarios, "missing from the submission")
        skipped.update(self.invalid_scenarios)
        return skipped

    def is_scenario_valid(self, scenario_id: str) -> bool:
        """False for a scenario with an error or missing from the submission (missing ones have a finding too)."""
        return scenario_id not in self.invalid_scenarios

    def _sorted_groups(self) -> list[FindingGroup]:
        order = list(CODES)
        return sorted(self.groups.values(), key=lambda g: (g.severity != ERROR, order.index(g.code)))

    def to_dict(self, include_skipped: bool = False) -> dict[str, Any]:
        """The report as JSON-ready data; include_skipped adds {scenario_id: reason} of every unscorable scenario."""
        s = self.stats
        data = {
            "submission": self.submission,
            "challenge": self.challenge,
            "valid": self.ok,
            "errors": self.error_count,
            "warnings": self.warning_count,
            "stats": {
                "shards": s.shards,
                "scenarios_expected": s.scenarios_expected,
                "scenarios_submitted": s.scenarios_submitted,
                "scenarios_valid": s.scenarios_valid,
                "scenarios_missing": len(self.missing_scenarios),
                "bytes_read": s.bytes_read,
                "elapsed_s": round(s.elapsed_s, 3),
                "scenarios_per_s": round(s.scenarios_per_s, 1),
            },
            "groups": [g.to_dict() for g in self._sorted_groups()],
            "max_listed": self.max_listed,
        }
        if include_skipped:
            data["skipped_scenarios"] = self.skipped_scenarios
        return data

    def format_text(self) -> str:
        s = self.stats
        verdict = "VALID" if self.ok else "INVALID"
        lines = [
            f"{self.submission}: {verdict} {self.challenge} submission — {self.error_count} error(s), "
            f"{self.warning_count} warning(s)",
            f"  {s.shards} shard(s), {s.scenarios_submitted} scenario(s) submitted, "
            f"{s.scenarios_valid} valid, {len(self.missing_scenarios)} missing of "
            f"{s.scenarios_expected} expected; {s.bytes_read} bytes in {s.elapsed_s:.2f} s "
            f"({s.scenarios_per_s:.1f} scenarios/s)",
        ]
        for g in self._sorted_groups():
            lines.append("")
            lines.append(f"{g.severity.upper()} {g.code} — {g.title}: {g.count}")
            for f in g.listed:
                lines.append(f"  - {f.message}")
            if g.count > len(g.listed):
                lines.append(f"  ... and {g.count - len(g.listed)} more (raise --max-listed to see them)")
            for hint, count in g.hints.items():
                lines.append(f"  hint ({count} of {g.count}): {hint}")
        return "\n".join(lines)
