"""Scenario Generation end to end: baselines, validation messages, scoring, the CLI, compare.

Synthetic scenes from `wosac_eval.sim` (no ../shared needed); parity with the
official outputs is in tests/parity.
"""
from __future__ import annotations

import json
from functools import lru_cache

import numpy as np
import pytest

from support.runs import run_cli
from wosac_eval.challenges import Challenge, spec
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import sim_agents_submission_pb2 as pb
from wosac_eval.scoring.scenario import score_scenario
from wosac_eval.sim import scenes
from wosac_eval.arrays.messages import rollouts_message
from wosac_eval.sim.baselines import policy_rollouts
from wosac_eval.validate import rules


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sg-scenes")
    # intersection (signals, turning traffic) and occlusion (logged invalid steps)
    chosen = [s for s in scenes.generate_scenes(5, seed=4) if s.scenario_id.split("-", 3)[-1] in
              ("intersection", "occlusion")]
    scenes.write_scenario_shards(chosen, folder, num_shards=1)
    return folder


@lru_cache(maxsize=None)
def _generated(folder: str, policy: str):
    out = {}
    for scenario, _ in iter_scenarios(folder):
        out[scenario.scenario_id] = (scenario, rollouts_message(policy_rollouts(scenario, policy, 0, "scenario_gen")))
    return out


def generated(folder, policy="log_replay_noise"):
    return _generated(str(folder), policy)


def test_generated_rollouts_cover_all_91_steps_with_boxes(scene_dir):
    for scenario, rollouts in generated(scene_dir).values():
        assert len(rollouts.joint_scenes) == 32
        t = rollouts.joint_scenes[0].simulated_trajectories[0]
        assert len(t.center_x) == len(t.length) == len(t.width) == len(t.height) == 91
        assert t.HasField("object_type") and all(t.valid)
        agents = rules.sim_agent_ids(scenario)
        assert rules.check_scenario_rollouts(rollouts, agents, challenge="scenario_gen") == []
        # The current state is the logged one: only the rest of the scene is generated.
        track = next(tr for tr in scenario.tracks if tr.id == t.object_id)
        now = track.states[10]
        assert (t.center_x[10], t.center_y[10]) == pytest.approx((now.center_x, now.center_y), abs=1e-3)


def _findings(rollouts, agents, challenge="scenario_gen"):
    return {(f.code, f.field): f for f in rules.check_scenario_rollouts(rollouts, agents, challenge=challenge)}


def test_box_and_type_faults_are_named_precisely(scene_dir):
    scenario, original = next(iter(generated(scene_dir).values()))
    agents = rules.sim_agent_ids(scenario)
    rollouts = pb.ScenarioRollouts.FromString(original.SerializeToString())
    scene = rollouts.joint_scenes[3]
    first, second, third, fourth = scene.simulated_trajectories[:4]
    del first.length[:]                      # missing sizes
    second.width[5] = -0.5                   # a negative size
    second.height[7] = 0.0                   # a zero size
    third.height[2] = float("nan")           # a non-finite size
    fourth.ClearField("object_type")         # no type
    del scene.simulated_trajectories[4].width[90]  # one value short
    found = _findings(rollouts, agents)
    msg = found[("rollouts.wrong_length", "length")].message
    assert f"rollout 3 object {first.object_id}" in msg and "field length has 0 values, expected 91" in msg
    assert "the official validator accepts it but its scorer fails on the scenario" in msg
    assert "length, width and height with one value per step (91)" in found[("rollouts.wrong_length", "length")].hint
    # Sizes the official scores as given, and a missing type (TYPE_UNSET): warnings, named as precisely.
    width = found[("rollouts.non_positive_size", "width")]
    assert "width[5] is -0.5; a box size is expected to be positive" in width.message and width.severity == "warning"
    assert "height[7] is 0" in found[("rollouts.non_positive_size", "height")].message
    assert "height[2] is NaN" in found[("rollouts.non_finite", "height")].message
    assert f"object {fourth.object_id}" in found[("rollouts.missing_object_type", "object_type")].message
    assert found[("rollouts.missing_object_type", "object_type")].severity == "warning"
    assert "field width has 90 values" in found[("rollouts.wrong_length", "width")].message
    # The sim agents rules on the same rollouts point at the challenge.
    sim_agents = _findings(original, agents, challenge="sim_agents")
    assert "--challenge scenario_gen" in sim_agents[("rollouts.wrong_length", "center_x")].hint
    assert sim_agents[("rollouts.ignored_field", "length")].severity == "warning"


def test_submitted_valid_flags_are_ignored_with_a_warning(scene_dir):
    scenario, original = next(iter(generated(scene_dir).values()))
    rollouts = pb.ScenarioRollouts.FromString(original.SerializeToString())
    t = rollouts.joint_scenes[0].simulated_trajectories[0]
    t.valid.extend([True] * 91)
    t.valid[40] = False
    found = _findings(rollouts, rules.sim_agent_ids(scenario))
    assert set(found) == {("rollouts.ignored_field", "valid")}
    assert found[("rollouts.ignored_field", "valid")].severity == "warning"
    # ... and ignored by the scorer, as officially.
    assert score_scenario(scenario, rollouts, challenge="scenario_gen") == score_scenario(
        scenario, original, challenge="scenario_gen")


def test_scoring_uses_the_submitted_sizes(scene_dir):
    scenario, original = next(iter(generated(scene_dir).values()))
    bigger = pb.ScenarioRollouts.FromString(original.SerializeToString())
    for scene in bigger.joint_scenes:
        for t in scene.simulated_trajectories:
            t.length[:] = [4 * v for v in t.length]
            t.width[:] = [4 * v for v in t.width]
    before = score_scenario(scenario, original, challenge="scenario_gen")
    after = score_scenario(scenario, bigger, challenge="scenario_gen")
    # Boxes four times as large collide and leave the road more often.
    assert after["simulated_collision_rate"] > before["simulated_collision_rate"]
    assert after["simulated_offroad_rate"] >= before["simulated_offroad_rate"]
    assert after["average_displacement_error"] == before["average_displacement_error"] == 0.0


def test_rollout_reader_equals_the_parsed_fields(scene_dir):
    """Trajectories read from the wire (from the message, and from the bytes it was parsed from) equal the
    parsed fields."""
    from wosac_eval.arrays import rollouts as rollouts_module
    _, original = next(iter(generated(scene_dir).values()))
    odd = pb.ScenarioRollouts.FromString(original.SerializeToString())
    odd.joint_scenes[1].simulated_trajectories[2].object_id = 2 ** 31 - 1  # a 5-byte id varint
    odd.joint_scenes[1].simulated_trajectories[3].object_id = -2  # a 10-byte one
    raw = odd.SerializeToString()
    for arrays in (rollouts_module.rollout_arrays(odd, "scenario_gen"),
                   rollouts_module.rollout_arrays(odd, "scenario_gen", raw)):
        for r, scene in enumerate(odd.joint_scenes):
            assert arrays.object_id[r].tolist() == [t.object_id for t in scene.simulated_trajectories]
            assert arrays.object_type[r].tolist() == [t.object_type for t in scene.simulated_trajectories]
            for field, name in (("x", "center_x"), ("heading", "heading"), ("length", "length"),
                                ("width", "width"), ("height", "height")):
                expected = np.array([getattr(t, name) for t in scene.simulated_trajectories], np.float32)
                np.testing.assert_array_equal(getattr(arrays, field)[r], expected, err_msg=field)
        assert arrays.object_id[1, 2] == 2 ** 31 - 1 and arrays.object_id[1, 3] == -2


@pytest.mark.slow  # among the longest outside Ray, browser and JAX (--durations): the full run's
def test_baseline_score_and_compare_commands(tmp_path, scene_dir):
    results = {}
    for policy in ("log_replay_noise", "constant_velocity"):
        out = tmp_path / f"{policy}.tar.gz"
        made = run_cli("baseline", "--challenge", "scenario_gen", "--scenarios", str(scene_dir), "--policy", policy,
                       "--output", str(out), "--workers", "1")
        assert made.returncode == 0, made.stderr
        assert "scenario_gen" in made.stdout and "validation: ok" in made.stdout
        checked = run_cli("validate", "--challenge", "scenario_gen", "--scenarios", str(scene_dir),
                          "--submission", str(out))
        assert checked.returncode == 0 and "VALID scenario_gen submission" in checked.stdout, checked.stdout
        wrong = run_cli("validate", "--scenarios", str(scene_dir), "--submission", str(out))
        assert wrong.returncode == 1 and "--challenge scenario_gen" in wrong.stdout
        scored = run_cli("score", "--challenge", "scenario_gen", "--scenarios", str(scene_dir), "--submission",
                         str(out), "-o", str(tmp_path / f"{policy}.json"))
        assert scored.returncode == 0, scored.stderr
        results[policy] = json.loads((tmp_path / f"{policy}.json").read_text())
    for result in results.values():
        assert result["challenge"] == "scenario_gen" and result["config"] == spec("scenario_gen").default_config
        assert result["num_scenarios"] == 2 and result["coverage"]["fraction"] == 1.0
        assert result["aggregate"]["min_average_displacement_error"] == 0.0
    # The log replay is the more realistic scene generator.
    assert (results["log_replay_noise"]["buckets"]["realism_meta_metric"]
            > results["constant_velocity"]["buckets"]["realism_meta_metric"])
    # The result is the per-scenario score_scenario, scenario by scenario.
    for sid, (scenario, rollouts) in generated(scene_dir).items():
        row = next(r for r in results["log_replay_noise"]["scenarios"] if r["scenario_id"] == sid)
        metrics = score_scenario(scenario, rollouts, challenge=Challenge.SCENARIO_GEN)
        assert {k: row[k] for k in metrics} == metrics
    # compare works within the challenge, refuses across challenges.
    same = run_cli("compare", str(tmp_path / "constant_velocity.json"), str(tmp_path / "log_replay_noise.json"))
    assert same.returncode == 0, same.stderr
    sim_agents = dict(results["log_replay_noise"], challenge="sim_agents", config="2025")
    (tmp_path / "sa.json").write_text(json.dumps(sim_agents))
    mixed = run_cli("compare", str(tmp_path / "sa.json"), str(tmp_path / "log_replay_noise.json"))
    assert mixed.returncode == 2
    assert "different challenges" in mixed.stderr and "sim_agents" in mixed.stderr
    report = run_cli("report", str(tmp_path / "log_replay_noise.json"), "--compare", str(tmp_path / "sa.json"),
                     "--html", str(tmp_path / "r.html"))
    assert report.returncode == 2 and "different challenges" in report.stderr
