"""Each validation rule, fed a real golden submission mutated in code."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.validate import coverage_rules, metadata_rules, rules
from support.submissions import golden_submission, load_scenario

SID = "637f20cafde22ff8"


@pytest.fixture(scope="module")
def scenario():
    return load_scenario(SID)


@pytest.fixture(scope="module")
def agents(scenario):
    return rules.sim_agent_ids(scenario)


@pytest.fixture
def submission():
    return golden_submission(f"{SID}__logreplay")


@pytest.fixture
def rollouts(submission):
    return submission.scenario_rollouts[0]


def codes(findings):
    return sorted(f.code for f in findings)


def only(findings, code):
    found = [f for f in findings if f.code == code]
    assert found, f"no {code} finding among {[f.message for f in findings]}"
    return found


# -- sim agents of a scenario --------------------------------------------------


def test_sim_agents_are_the_objects_valid_at_step_10(scenario, agents):
    expected = sorted(t.id for t in scenario.tracks if t.states[10].valid)
    assert agents.tolist() == expected
    assert 0 < len(agents) < len(scenario.tracks)  # some tracks are not valid at step 10


def test_track_shorter_than_current_step_is_not_a_sim_agent(scenario):
    from wosac_eval.protos import scenario_pb2

    short = scenario_pb2.Scenario()
    short.CopyFrom(scenario)
    del short.tracks[0].states[5:]
    assert short.tracks[0].id not in rules.sim_agent_ids(short).tolist()


# -- golden submissions are valid ------------------------------------------------


@pytest.mark.parametrize(
    "case",
    [
        "637f20cafde22ff8__logreplay",
        "637f20cafde22ff8__logreplay_noise05",
        "637f20cafde22ff8__official_test_submission",
        "637f20cafde22ff8__stationary",
        "ee519cf571686d19__constvel_noise",
        "ee519cf571686d19__logreplay_noise2",
    ],
)
def test_golden_submissions_pass_every_rule(case):
    sub = golden_submission(case)
    ids = rules.sim_agent_ids(load_scenario(case.split("__")[0]))
    assert metadata_rules.check_metadata(sub, "g") == []
    for r in sub.scenario_rollouts:
        assert rules.check_scenario_rollouts(r, ids, shard="g") == []


# -- metadata ------------------------------------------------------------------


@pytest.mark.parametrize(
    "field,code,fragment",
    [
        ("submission_type", "metadata.missing", "submission_type is not set"),
        ("account_name", "metadata.missing", "account_name is empty"),
        ("unique_method_name", "metadata.missing", "unique_method_name is empty"),
        ("authors", "metadata.missing", "authors is empty"),
        ("affiliation", "metadata.missing", "affiliation is empty"),
        ("description", "metadata.missing", "description is empty"),
        ("uses_lidar_data", "metadata.missing", "uses_lidar_data is not set"),
        ("uses_camera_data", "metadata.missing", "uses_camera_data is not set"),
        ("uses_public_model_pretraining", "metadata.missing", "uses_public_model_pretraining is not set"),
        ("num_model_parameters", "metadata.missing", "num_model_parameters is empty"),
        (
            "acknowledge_complies_with_closed_loop_requirement",
            "metadata.missing",
            "acknowledge_complies_with_closed_loop_requirement is not set",
        ),
    ],
)
def test_cleared_metadata_field_is_named(submission, field, code, fragment):
    submission.ClearField(field)
    findings = metadata_rules.check_metadata(submission, "shard-7.binproto")
    assert codes(findings) == [code]
    (f,) = findings
    assert f.field == field and f.shard == "shard-7.binproto"
    assert f.message.startswith(f"shard-7.binproto: {fragment}")


def test_method_link_is_only_a_warning(submission):
    submission.ClearField("method_link")
    (f,) = metadata_rules.check_metadata(submission, "s")
    assert (f.code, f.severity, f.field) == ("metadata.recommended", "warning", "method_link")


@pytest.mark.parametrize(
    "mutate,field,fragment",
    [
        (
            lambda s: setattr(s, "submission_type", 0),
            "submission_type",
            "submission_type is UNKNOWN, expected SIM_AGENTS_SUBMISSION",
        ),
        (lambda s: setattr(s, "account_name", "jdoe"), "account_name", "account_name 'jdoe' is not an email address"),
        (lambda s: s.authors.append("  "), "authors", "authors[1] is empty"),
        (
            lambda s: setattr(s, "num_model_parameters", "about 3 million"),
            "num_model_parameters",
            "'about 3 million' is not a number",
        ),
        (
            lambda s: setattr(s, "acknowledge_complies_with_closed_loop_requirement", False),
            "acknowledge_complies_with_closed_loop_requirement",
            "is false; it must be true",
        ),
    ],
)
def test_invalid_metadata_value_is_named(submission, mutate, field, fragment):
    mutate(submission)
    (f,) = metadata_rules.check_metadata(submission, "s")
    assert (f.code, f.field) == ("metadata.invalid", field)
    assert fragment in f.message


@pytest.mark.parametrize("value", ["200K", "1.5B", "7000000", "3m", "12 M"])
def test_parameter_counts_with_suffix_are_accepted(submission, value):
    submission.num_model_parameters = value
    assert metadata_rules.check_metadata(submission, "s") == []


def test_pretraining_needs_model_names(submission):
    submission.uses_public_model_pretraining = True
    (f,) = metadata_rules.check_metadata(submission, "s")
    assert f.field == "public_model_names" and "uses_public_model_pretraining is true" in f.message
    submission.public_model_names.append("llama-3-8b")
    assert metadata_rules.check_metadata(submission, "s") == []


def test_metadata_differing_between_shards_names_both(submission):
    other = sim_agents_submission_pb2.SimAgentsChallengeSubmission()
    other.CopyFrom(submission)
    other.unique_method_name = "another-name"
    other.uses_lidar_data = True
    findings = metadata_rules.check_metadata_consistency(
        metadata_rules.metadata_of(submission), "a.binproto", metadata_rules.metadata_of(other), "b.binproto"
    )
    assert [f.field for f in findings] == ["unique_method_name", "uses_lidar_data"]
    assert findings[0].message == "b.binproto: unique_method_name is 'another-name' but 'logreplay' in a.binproto"


# -- coverage ------------------------------------------------------------------


def test_missing_scenarios_listed_in_scenario_set_order():
    findings = coverage_rules.check_missing_scenarios(["a", "b", "c", "d"], {"b"})
    assert [f.scenario_id for f in findings] == ["a", "c", "d"]
    assert findings[0].message == "scenario a: missing from the submission (3 scenario(s) of the set are missing)"


def test_unknown_and_duplicate_scenario_messages():
    assert (
        coverage_rules.unknown_scenario("zz", "s1", 4).message
        == "s1: scenario zz: not in the scenario set (scenario_rollouts[4])"
    )
    dup = coverage_rules.duplicate_scenario("ab", "s2", 0, ("s1", 3))
    assert (
        dup.message == "s2: scenario ab: submitted again at scenario_rollouts[0]; first in s1 at scenario_rollouts[3]"
    )


# -- per scenario rollouts -----------------------------------------------------


def test_wrong_rollout_count_gives_count_found(rollouts, agents):
    del rollouts.joint_scenes[31]
    (f,) = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert f.code == "rollouts.wrong_count"
    assert f.message == f"s: scenario {SID}: found 31 joint scenes, expected 32; the official validator refuses it"
    rollouts.joint_scenes.add().CopyFrom(rollouts.joint_scenes[0])
    rollouts.joint_scenes.add().CopyFrom(rollouts.joint_scenes[0])
    (f,) = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert "found 33 joint scenes, expected 32" in f.message


def test_missing_sim_agents_listed_by_id(rollouts, agents):
    scene = rollouts.joint_scenes[3]
    gone = sorted([scene.simulated_trajectories[0].object_id, scene.simulated_trajectories[7].object_id])
    del scene.simulated_trajectories[7]
    del scene.simulated_trajectories[0]
    (f,) = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert (f.code, f.rollout, f.scenario_id) == ("rollouts.missing_sim_agents", 3, SID)
    assert f.message.startswith(
        f"s: scenario {SID} rollout 3: missing sim agents [{gone[0]}, {gone[1]}] (2 of {len(agents)}"
    )


def test_extra_objects_are_named(rollouts, agents, scenario):
    not_sim_agent = next(t.id for t in scenario.tracks if not t.states[10].valid)
    scene = rollouts.joint_scenes[5]
    extra = scene.simulated_trajectories.add()
    extra.CopyFrom(scene.simulated_trajectories[0])
    extra.object_id = not_sim_agent
    (f,) = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert (f.code, f.rollout) == ("rollouts.extra_objects", 5)
    assert f"objects [{not_sim_agent}] are not sim agents" in f.message


def test_duplicated_object_ids_are_counted(rollouts, agents):
    scene = rollouts.joint_scenes[2]
    oid = scene.simulated_trajectories[4].object_id
    for _ in range(2):
        scene.simulated_trajectories.add().CopyFrom(scene.simulated_trajectories[4])
    (f,) = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert f.code == "rollouts.duplicate_objects"
    assert f"object ids simulated more than once: {oid} (3 times)" in f.message


def test_trajectory_without_object_id(rollouts, agents):
    scene = rollouts.joint_scenes[9]
    oid = scene.simulated_trajectories[2].object_id
    scene.simulated_trajectories[2].ClearField("object_id")
    findings = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert codes(findings) == ["rollouts.missing_object_id", "rollouts.missing_sim_agents"]
    assert (
        "rollout 9: simulated_trajectories[2] has no object_id"
        in only(findings, "rollouts.missing_object_id")[0].message
    )
    assert f"missing sim agents [{oid}]" in only(findings, "rollouts.missing_sim_agents")[0].message


@pytest.mark.parametrize("field", rules.TRAJECTORY_FIELDS)
@pytest.mark.parametrize("size", [79, 81, 0])
def test_wrong_length_names_object_field_and_count(rollouts, agents, field, size):
    trajectory = rollouts.joint_scenes[4].simulated_trajectories[6]
    values = list(getattr(trajectory, field))
    trajectory.ClearField(field)
    getattr(trajectory, field).extend((values + values)[:size])
    (f,) = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert (f.code, f.rollout, f.object_id, f.field) == ("rollouts.wrong_length", 4, trajectory.object_id, field)
    assert (
        f.message
        == f"s: scenario {SID} rollout 4 object {trajectory.object_id}: field {field} has {size} values, expected 80; the official validator refuses it"
    )


@pytest.mark.parametrize("field", rules.TRAJECTORY_FIELDS)
@pytest.mark.parametrize("value,kind", [(math.nan, "NaN"), (math.inf, "+inf"), (-math.inf, "-inf")])
def test_non_finite_value_names_its_index(rollouts, agents, field, value, kind):
    trajectory = rollouts.joint_scenes[5].simulated_trajectories[11]
    getattr(trajectory, field)[17] = value
    (f,) = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert (f.code, f.rollout, f.object_id, f.field) == ("rollouts.non_finite", 5, trajectory.object_id, field)
    assert f.severity == "warning"  # the official scores it; so does wosac-eval
    assert f.message == (
        f"s: scenario {SID} rollout 5 object {trajectory.object_id}: {field}[17] is {kind}; "
        "the official evaluator scores it as given, NaN spreading into its features (so does wosac-eval)"
    )


def test_several_non_finite_values_counted_and_indexed(rollouts, agents):
    trajectory = rollouts.joint_scenes[0].simulated_trajectories[0]
    for i in (3, 40, 79):
        trajectory.heading[i] = math.nan
    (f,) = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert f.message.endswith(
        "heading[3] is NaN (3 non-finite values, at indices [3, 40, 79])" + rules._NON_FINITE_OFFICIAL
    )


def test_non_finite_found_in_a_trajectory_of_wrong_length(rollouts, agents):
    # Wrong lengths take the per-field fallback path, not the stacked fast path.
    trajectory = rollouts.joint_scenes[1].simulated_trajectories[1]
    trajectory.center_x.append(math.inf)
    findings = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert codes(findings) == ["rollouts.non_finite", "rollouts.wrong_length"]
    assert only(findings, "rollouts.non_finite")[0].message.endswith(
        "center_x[80] is +inf" + rules._NON_FINITE_OFFICIAL
    )


def test_unknown_layout_falls_back_and_still_finds_nan(rollouts, agents):
    # An unknown field 1 serializes before center_x: the fast path's header check
    # must reject the layout and the fallback must still see the NaN.
    trajectory = rollouts.joint_scenes[1].simulated_trajectories[2]
    trajectory.center_z[0] = math.nan
    raw = b"\x08\x05" + trajectory.SerializeToString()
    trajectory.Clear()
    trajectory.MergeFromString(raw)
    (f,) = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert f.message.endswith("center_z[0] is NaN" + rules._NON_FINITE_OFFICIAL)


def test_unknown_scenario_still_gets_structural_checks(rollouts):
    rollouts.joint_scenes[0].simulated_trajectories[0].center_x[0] = math.nan
    (f,) = rules.check_scenario_rollouts(rollouts, None, shard="s")
    assert f.code == "rollouts.non_finite"


def test_every_fault_of_a_scenario_is_reported_not_just_the_first(rollouts, agents):
    rollouts.joint_scenes[0].simulated_trajectories[0].center_y[1] = math.nan
    del rollouts.joint_scenes[1].simulated_trajectories[0].heading[-1]
    del rollouts.joint_scenes[2].simulated_trajectories[0]
    del rollouts.joint_scenes[31]
    findings = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert codes(findings) == [
        "rollouts.missing_sim_agents",
        "rollouts.non_finite",
        "rollouts.wrong_count",
        "rollouts.wrong_length",
    ]


def test_empty_joint_scene_misses_every_sim_agent(rollouts, agents):
    del rollouts.joint_scenes[0].simulated_trajectories[:]
    (f,) = rules.check_scenario_rollouts(rollouts, agents, shard="s")
    assert f.code == "rollouts.missing_sim_agents" and f"({len(agents)} of {len(agents)}" in f.message
    assert np.asarray(agents).size > 20 and "more)" in f.message  # long lists are cut, with a count
