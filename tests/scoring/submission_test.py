"""Splitting shards for the workers: the same scenarios and bytes a full parse gives."""

from wosac_eval.parse.shards import split_shard as _split_shard
from wosac_eval.protos import sim_agents_submission_pb2 as pb


def shard(*scenario_ids):
    submission = pb.SimAgentsChallengeSubmission(account_name="a", unique_method_name="m")
    for sid in scenario_ids:
        rollouts = submission.scenario_rollouts.add(scenario_id=sid)
        rollouts.joint_scenes.add().simulated_trajectories.add(
            object_id=3, center_x=[1.0], center_y=[2.0], center_z=[0.0], heading=[0.5]
        )
    return submission


def test_split_equals_parse():
    submission = shard("a", "b", "a")  # a repeated scenario stays listed twice (validation decides)
    items = _split_shard("s0", submission.SerializeToString())
    assert [sid for sid, _ in items] == ["a", "b", "a"]
    assert [pb.ScenarioRollouts.FromString(data) for _, data in items] == list(submission.scenario_rollouts)


def test_scenario_id_written_twice_counts_once_like_a_parse():
    first = pb.ScenarioRollouts(scenario_id="old").SerializeToString()
    second = pb.ScenarioRollouts(scenario_id="new").SerializeToString()
    element = first + second  # two scenario_id fields in one element: the last one wins when parsed
    raw = bytes([0x0A, len(element)]) + element
    assert pb.SimAgentsChallengeSubmission.FromString(raw).scenario_rollouts[0].scenario_id == "new"
    assert [sid for sid, _ in _split_shard("s0", raw)] == ["new"]


def test_malformed_shard_gives_nothing():
    assert _split_shard("s0", b"\x0a\x05ab") == []
