"""Errors only for what the official evaluator (waymo-open-dataset 1.6.7) refuses or cannot score.

What the official does with each case was checked with its code (../shared/oracle):
- a scenario-gen joint scene without box sizes (the official test's: zero positions, 91 steps, no
  sizes, no type) passes the official `validate_scenario_rollouts`, but its scorer fails stacking
  the sizes with the positions (so does any other count of size values): an error here, saying so;
- zero or negative sizes, as the log's boxes on a track's invalid steps (`scenario_to_joint_scene`),
  and an unset object_type are scored (the metrics use the logged types): warnings here, and scored
  the same way (golden cases `tests/data/oracle_scenario_gen/*__sg_logged_boxes`, `*__sg_odd_boxes`);
- a repeated object id passes the official validator and fails its scorer: an error, saying so.
"""

from __future__ import annotations

import numpy as np
import pytest

from support.paths import TEST_DATA
from wosac_eval.compat.converters import scenario_to_joint_scene
from wosac_eval import read_scenarios
from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.validate import rules
from wosac_eval.validate.findings import ERROR, WARNING, ValidationReport

OCCLUSION = TEST_DATA / "oracle_scenario_gen" / "scenes" / "synthetic-5-004-occlusion.tfrecord"


@pytest.fixture(scope="module")
def scene():
    return next(iter(read_scenarios([OCCLUSION])))


def official_test_rollouts(scenario, n_steps=91):
    """The official tests' joint scene: every sim agent at zero, no box sizes, no object type."""
    trajectories = [
        sim_agents_submission_pb2.SimulatedTrajectory(
            object_id=int(i),
            center_x=[0.0] * n_steps,
            center_y=[0.0] * n_steps,
            center_z=[0.0] * n_steps,
            heading=[0.0] * n_steps,
        )
        for i in rules.sim_agent_ids(scenario)
    ]
    scene = sim_agents_submission_pb2.JointScene(simulated_trajectories=trajectories)
    return sim_agents_submission_pb2.ScenarioRollouts(scenario_id=scenario.scenario_id, joint_scenes=[scene] * 32)


def by_code(findings):
    out = {}
    for f in findings:
        out.setdefault(f.code, []).append(f)
    return out


def test_official_test_joint_scene_for_scenario_gen(scene):
    rollouts = official_test_rollouts(scene)
    found = by_code(rules.check_scenario_rollouts(rollouts, rules.sim_agent_ids(scene), challenge="scenario_gen"))
    assert set(found) == {"rollouts.wrong_length", "rollouts.missing_object_type"}
    n = 32 * len(rules.sim_agent_ids(scene))
    # Sizes: accepted by the official validator, but its scorer cannot score the scenario: an error.
    lengths = found["rollouts.wrong_length"]
    assert len(lengths) == 3 * n and {f.field for f in lengths} == {"length", "width", "height"}
    assert {f.severity for f in lengths} == {ERROR}
    assert lengths[0].message.endswith(
        "field length has 0 values, expected 91; the official validator accepts it but its scorer fails on the scenario"
    )
    assert "one value per step (91)" in lengths[0].hint
    # No type: the official scores it as TYPE_UNSET: a warning.
    types = found["rollouts.missing_object_type"]
    assert len(types) == n and {f.severity for f in types} == {WARNING}
    assert "the official evaluator scores it as TYPE_UNSET" in types[0].message


def test_logged_joint_scene_is_valid_for_scenario_gen(scene):
    logged = scenario_to_joint_scene(scene, "scenario_gen")
    assert any(v == 0 for t in logged.simulated_trajectories for v in t.length)  # occluded steps: size 0
    rollouts = sim_agents_submission_pb2.ScenarioRollouts(scenario_id=scene.scenario_id, joint_scenes=[logged] * 32)
    findings = rules.check_scenario_rollouts(rollouts, rules.sim_agent_ids(scene), challenge="scenario_gen")
    # The log's validity is submitted too, and ignored (the evaluator takes the log's at step 10).
    assert {f.code for f in findings} == {"rollouts.non_positive_size", "rollouts.ignored_field"}
    assert {f.severity for f in findings} == {WARNING}
    f = by_code(findings)["rollouts.non_positive_size"][0]
    assert f.field in ("length", "width", "height") and f.object_id is not None and f.rollout == 0
    assert f.message.split(": ", 1)[1].startswith(f"{f.field}[")
    assert "the official evaluator scores it as given" in f.message
    report = ValidationReport("s", challenge="scenario_gen")
    report.extend(findings)
    assert report.ok


def test_logged_joint_scene_of_a_real_scenario_is_valid_for_scenario_gen():
    from support.submissions import load_scenario

    scenario = load_scenario("637f20cafde22ff8")  # skips without ../shared
    logged = scenario_to_joint_scene(scenario, "scenario_gen")
    rollouts = sim_agents_submission_pb2.ScenarioRollouts(scenario_id=scenario.scenario_id, joint_scenes=[logged] * 32)
    findings = rules.check_scenario_rollouts(rollouts, rules.sim_agent_ids(scenario), challenge="scenario_gen")
    assert findings and {f.severity for f in findings} == {WARNING}


def test_repeated_object_says_the_official_scorer_fails(scene):
    rollouts = official_test_rollouts(scene, n_steps=80)
    scene0 = rollouts.joint_scenes[0]
    scene0.simulated_trajectories.append(scene0.simulated_trajectories[0])
    (f,) = by_code(rules.check_scenario_rollouts(rollouts, rules.sim_agent_ids(scene)))["rollouts.duplicate_objects"]
    assert f.severity == ERROR and f.message.endswith(
        "the official validator accepts it but its scorer fails on the scenario (repeated ids)"
    )


def test_wrong_challenge_hint_is_one_line_per_cause(scene):
    # A sim agents submission (80 steps, no boxes) validated for scenario gen: thousands of findings,
    # each cause explained once, with its count, not on every line.
    rollouts = official_test_rollouts(scene, n_steps=80)
    findings = rules.check_scenario_rollouts(rollouts, rules.sim_agent_ids(scene), challenge="scenario_gen")
    report = ValidationReport("sub.binproto", max_listed=10_000, challenge="scenario_gen")
    report.extend(findings)
    n = 32 * len(rules.sim_agent_ids(scene))
    text = report.format_text()
    lines = text.splitlines()
    wrong = [line for line in lines if "is a sim_agents submission" in line]
    assert wrong == [
        f"  hint ({4 * n} of {7 * n}): 80 values is a sim_agents submission: validate and score it "
        "with --challenge sim_agents"
    ]
    assert sum("one value per step" in line for line in lines) == 1
    assert sum(line.startswith("  hint (") for line in lines) == 3  # sizes, wrong challenge, missing type
    assert sum(line.startswith("  - ") for line in lines) == 8 * n  # every finding listed, without its hint
    group = next(g for g in report.to_dict()["groups"] if g["code"] == "rollouts.wrong_length")
    assert [h["count"] for h in group["hints"]] == [4 * n, 3 * n]
    assert all("hint" not in f for f in group["listed"])


def test_sim_agents_rollouts_for_scenario_gen_length_hint(scene):
    rollouts = official_test_rollouts(scene, n_steps=91)
    findings = rules.check_scenario_rollouts(rollouts, rules.sim_agent_ids(scene))
    assert {f.code for f in findings} == {"rollouts.wrong_length"}
    assert {f.hint for f in findings} == {
        "91 values is a scenario_gen submission: validate and score it with --challenge scenario_gen"
    }
    assert np.all([f.message.endswith("expected 80; the official validator refuses it") for f in findings])
