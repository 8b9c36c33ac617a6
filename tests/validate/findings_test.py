"""The report: grouping by code, counts, the first N in full, warnings that do not invalidate."""

from __future__ import annotations

import json

import pytest

from wosac_eval.validate.findings import WARNING, Location, ValidationReport, format_ids, make_finding, where


def test_location_prefix_names_what_applies():
    assert where("s.binproto", "ab12", 3, 1234) == "s.binproto: scenario ab12 rollout 3 object 1234"
    assert where(scenario_id="ab12") == "scenario ab12"
    assert where("s.binproto") == "s.binproto"


def test_report_keeps_counts_and_first_n_per_code():
    report = ValidationReport("sub.tar.gz", max_listed=2)
    for i in range(5):
        report.add(
            make_finding("rollouts.wrong_count", f"found {i} joint scenes, expected 32", Location(scenario_id=f"s{i}"))
        )
    report.add(make_finding("metadata.recommended", "method_link is empty", Location("a"), severity=WARNING))
    assert not report.ok and report.error_count == 5 and report.warning_count == 1
    assert report.count("rollouts.wrong_count") == 5
    assert [f.scenario_id for f in report.findings("rollouts.wrong_count")] == ["s0", "s1"]
    assert set(report.invalid_scenarios) == {f"s{i}" for i in range(5)}  # all remembered, not only those listed
    text = report.format_text()
    assert "ERROR rollouts.wrong_count — Wrong number of joint scenes (rollouts): 5" in text
    assert "  ... and 3 more (raise --max-listed to see them)" in text
    assert text.index("ERROR") < text.index("WARNING")  # errors first
    json.dumps(report.to_dict())


def test_warnings_alone_keep_a_submission_valid():
    report = ValidationReport()
    report.add(make_finding("container.not_gzipped", "plain tar", severity=WARNING))
    assert report.ok and "VALID sim_agents submission — 0 error(s), 1 warning(s)" in report.format_text()


def test_max_listed_zero_counts_only():
    report = ValidationReport(max_listed=0)
    report.add(make_finding("shard.empty", "holds no scenario_rollouts", Location("x")))
    assert report.count("shard.empty") == 1 and report.findings() == []


def test_unknown_code_is_a_programming_error():
    with pytest.raises(KeyError):
        make_finding("no.such.code", "x")


def test_long_id_lists_are_cut_with_a_count():
    assert format_ids(range(3)) == "[0, 1, 2]"
    assert format_ids(range(25), limit=2) == "[0, 1, ... (+23 more)]"


def test_control_characters_in_names_cannot_forge_report_lines():
    f = make_finding("coverage.unknown_scenario", "not in the scenario set", Location("a\nb", "x\nERROR fake"))
    assert "\n" not in f.message
    assert f.message == "'a\\nb': scenario 'x\\nERROR fake': not in the scenario set"


def test_hints_are_counted_per_group_and_merged_not_repeated():
    def finding(hint):
        return make_finding(
            "rollouts.wrong_length",
            "field heading has 91 values, expected 80",
            Location(scenario_id="s"),
            field="heading",
            hint=hint,
        )

    first = ValidationReport("sub", max_listed=2)
    first.extend([finding("cause A"), finding("cause A"), finding(None)])
    second = ValidationReport("sub", max_listed=2)
    second.extend([finding("cause A"), finding("cause B")])
    first.merge(second)
    group = first.groups["rollouts.wrong_length"]
    assert group.count == 5 and group.hints == {"cause A": 3, "cause B": 1}
    text = first.format_text()
    assert text.count("cause A") == 1 and "  hint (3 of 5): cause A" in text and "  hint (1 of 5): cause B" in text
    assert first.to_dict()["groups"][0]["hints"] == [{"hint": "cause A", "count": 3}, {"hint": "cause B", "count": 1}]
    assert "hint" not in first.to_dict()["groups"][0]["listed"][0]
    assert "hints" not in ValidationReport("x").to_dict()  # no hint: no key
