"""Tests of the baseline policies and the submission writer, on synthetic and (when present) real scenes."""

from __future__ import annotations

import functools
import tarfile

import numpy as np
import pytest

from wosac_eval.parse.shard_walk import iter_submission_shards
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import map_pb2, sim_agents_submission_pb2
from wosac_eval.sim import baselines, policies, scenes
from wosac_eval.sim import geometry as geo
from wosac_eval.sim.logged_scenes import colliding_pairs
from wosac_eval.sim.scene_recipes import SCENE_KINDS
from wosac_eval.validate import validate_submission

from support.paths import SHARED

REAL = SHARED / "womd" / "motion_data_one_scenario.tfrecord"


@functools.lru_cache(maxsize=None)
def scene(kind: str):
    return scenes.generate_scene(0, SCENE_KINDS.index(kind))


def sim_agent_ids(sc) -> list[int]:
    return [t.id for t in sc.tracks if t.states[10].valid]


@pytest.mark.parametrize("policy", sorted(policies.POLICIES))
def test_policy_output_shape_and_ids(policy):
    sc = scene("intersection")
    ids, traj = policies.simulate_scenario(sc, policy)
    assert ids.tolist() == sim_agent_ids(sc)
    assert traj.shape == (32, len(ids), 80, 4)
    assert np.isfinite(traj).all()
    assert np.all(np.abs(traj[..., 3]) <= np.pi)
    again = policies.simulate_scenario(sc, policy)[1]
    np.testing.assert_array_equal(traj, again)  # seeded: reproducible


def test_constant_velocity_extrapolates_the_current_velocity():
    sc = scene("dense_following")
    ctx = policies.context_from_scenario(sc)
    _, traj = policies.simulate_scenario(sc, "constant_velocity")
    step = np.diff(traj[0, :, :, :2], axis=1) / 0.1
    np.testing.assert_allclose(step, np.broadcast_to(ctx.velocity[:, None], step.shape), atol=1e-6)
    np.testing.assert_allclose(traj[0, :, :, 3], np.broadcast_to(ctx.heading[:, 10, None], (len(ctx.x), 80)))
    assert (traj == traj[:1]).all(), "deterministic: all rollouts equal"


def test_log_replay_noise_stays_near_the_log_and_differs_between_rollouts():
    sc = scene("intersection")
    ctx = policies.context_from_scenario(sc)
    _, traj = policies.simulate_scenario(sc, "log_replay_noise")
    logged = ~np.isnan(ctx.log_future[..., 0])
    error = np.linalg.norm(traj[..., :2] - ctx.log_future[None, ..., :2], axis=-1)[:, logged]
    assert np.median(error) < 0.6 and error.max() < 5.0
    assert np.abs(traj[0] - traj[1]).max() > 0.01
    # Smooth: no jump larger than the fastest logged motion allows.
    assert np.abs(np.diff(traj[..., :2], axis=2)).max() < 3.0


def test_idm_vehicles_stop_at_the_red_light_the_logged_runner_ignored():
    sc = scene("red_light")
    (runner_index,) = sc.objects_of_interest
    runner = sc.tracks[runner_index]
    ids, traj = policies.simulate_scenario(sc, "idm")
    k = ids.tolist().index(runner.id)
    red = [
        t
        for t in range(11, 91)
        if all(
            ls.state == map_pb2.TrafficSignalLaneState.LANE_STATE_STOP
            for ls in sc.dynamic_map_states[t].lane_states
            if abs(ls.stop_point.x - runner.states[10].center_x) + abs(ls.stop_point.y - runner.states[10].center_y)
            < 60
            and _ahead(runner, ls.stop_point)
        )
    ]
    assert len(red) > 20, "the runner's light stays red for a while"
    stop_points = [ls.stop_point for ls in sc.dynamic_map_states[10].lane_states if _ahead(runner, ls.stop_point)]
    nearest = min(
        stop_points, key=lambda p: np.hypot(p.x - runner.states[10].center_x, p.y - runner.states[10].center_y)
    )
    h = runner.states[10].heading
    along = (traj[:, k, :, 0] - nearest.x) * np.cos(h) + (traj[:, k, :, 1] - nearest.y) * np.sin(h)
    steps = np.array(red) - 11
    assert (along[:, steps] < 0.5).all(), "every rollout waits behind the stop point while red"
    # The log, by contrast, runs the red light.
    logged = np.array(
        [(s.center_x - nearest.x) * np.cos(h) + (s.center_y - nearest.y) * np.sin(h) for s in runner.states[11:]]
    )
    assert (logged[steps] > 0.5).any()


def _ahead(track, point) -> bool:
    s = track.states[10]
    dx, dy = point.x - s.center_x, point.y - s.center_y
    along = dx * np.cos(s.heading) + dy * np.sin(s.heading)
    across = -dx * np.sin(s.heading) + dy * np.cos(s.heading)
    return along > 0 and abs(across) < 1.5


def test_idm_follows_lanes_without_collisions_in_dense_traffic():
    sc = scene("dense_following")
    ctx = policies.context_from_scenario(sc)
    ids, traj = policies.simulate_scenario(sc, "idm")
    pairs = 0
    for r in range(0, 32, 8):
        x, y, h = traj[r, :, :, 0], traj[r, :, :, 1], traj[r, :, :, 3]
        pairs += len(colliding_pairs(x, y, h, ctx.length, ctx.width))
    assert pairs == 0
    speed = np.linalg.norm(np.diff(traj[..., :2], axis=2), axis=-1) / 0.1
    assert speed.max() < 25.0
    turn = np.abs(geo.wrap_angle(np.diff(traj[..., 3], axis=2))) / 0.1
    assert turn.max() < 1.5


@pytest.mark.skipif(not REAL.exists(), reason="../shared (real WOMD scenario) is absent")
@pytest.mark.parametrize("policy", sorted(policies.POLICIES))
def test_policies_run_on_real_womd(policy):
    (sourced,) = list(iter_scenarios(REAL))
    sc = sourced.scenario
    ids, traj = policies.simulate_scenario(sc, policy)
    assert ids.tolist() == sim_agent_ids(sc)
    assert traj.shape == (32, len(ids), 80, 4) and np.isfinite(traj).all()
    speed = np.linalg.norm(np.diff(traj[..., :2], axis=2), axis=-1) / 0.1
    assert np.percentile(speed, 99) < 30.0


def test_baseline_submissions_validate_with_full_metadata(tmp_path):
    scenario_paths = scenes.write_scenario_shards(
        [scene("intersection"), scene("occlusion"), scene("cyclists")], tmp_path / "scenarios", 2
    )
    for policy in sorted(policies.POLICIES):
        out = baselines.make_submission(scenario_paths, policy, tmp_path / f"{policy}.tar.gz", num_shards=2)
        report = validate_submission(scenario_paths, out)
        assert report.ok, report.format_text()
        assert report.warning_count == 0, report.format_text()
        with tarfile.open(out) as tar:
            names = sorted(tar.getnames())
        method = policy.replace("_", "-")
        assert names == [f"{method}.binproto-00000-of-00002", f"{method}.binproto-00001-of-00002"]
        shards = list(iter_submission_shards(out))
        assert len(shards) == 2
        for shard in shards:
            _name, data = shard
            msg = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(data)
            assert msg.submission_type == msg.SIM_AGENTS_SUBMISSION
            assert msg.unique_method_name == method and "@" in msg.account_name
            assert msg.HasField("acknowledge_complies_with_closed_loop_requirement")
            for field in ("uses_lidar_data", "uses_camera_data", "uses_public_model_pretraining"):
                assert msg.HasField(field)
            assert msg.num_model_parameters and msg.authors and msg.affiliation and msg.description


@pytest.mark.skipif(not REAL.exists(), reason="../shared (real WOMD scenario) is absent")
def test_baseline_submission_for_real_womd_validates(tmp_path):
    out = baselines.make_submission([REAL], "constant_velocity", tmp_path / "cv")
    assert sorted(p.name for p in out.iterdir()) == ["constant-velocity.binproto-00000-of-00001"]
    assert validate_submission([REAL], out).ok


def test_streamed_shards_are_the_canonical_serialisation(tmp_path):
    from wosac_eval.arrays.messages import rollouts_from_arrays, rollouts_message
    from wosac_eval.arrays.submission_writer import SubmissionMetadata, SubmissionWriter, build_shards

    arrays = []
    for kind in ("intersection", "collision", "cyclists"):
        sc = scene(kind)
        ids, traj = policies.simulate_scenario(sc, "constant_velocity", num_rollouts=32)
        arrays.append(rollouts_from_arrays(sc.scenario_id, ids, *np.moveaxis(traj, -1, 0)))
    msgs = [rollouts_message(a) for a in arrays]
    meta = SubmissionMetadata(unique_method_name="cv")
    with SubmissionWriter(meta, tmp_path / "folder", num_shards=2) as writer:
        for a in arrays:
            writer.add(a)
    expected = dict(build_shards(msgs, meta, 2))
    written = {p.name: p.read_bytes() for p in (tmp_path / "folder").iterdir()}
    assert written == expected
    # Fewer scenarios than shards: only as many shards, named accordingly; no temporary files left.
    with SubmissionWriter(meta, tmp_path / "one.tar.gz", num_shards=4) as writer:
        writer.add(msgs[0])
    with tarfile.open(tmp_path / "one.tar.gz") as tar:
        assert tar.getnames() == ["cv.binproto-00000-of-00001"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder", "one.tar.gz"]
