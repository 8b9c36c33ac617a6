"""`waymo_open_dataset.utils.sim_agents.submission_specs`, without TensorFlow.

`ChallengeType` is `wosac_eval.Challenge` (the same values, "sim_agents" and
"scenario_gen"); the validators raise `ValueError`, as the official ones do,
with wosac-eval's precise messages (scenario, rollout, object, field) and its
stricter checks (non-finite values, repeated objects, scenario-gen box sizes).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from wosac_eval import challenges
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2

ChallengeType = challenges.Challenge


@dataclasses.dataclass(frozen=True)
class SubmissionConfig:
    """What a valid submission of a challenge looks like.

    Attributes:
      current_time_index: the step every sim agent is valid at (10, the 11th).
      n_simulation_steps: steps per submitted trajectory (80 sim agents, 91 scenario gen).
      n_rollouts: joint scenes per scenario (32).
      step_duration_seconds: 0.1 (10 Hz).
    """

    current_time_index: int
    n_simulation_steps: int
    n_rollouts: int
    step_duration_seconds: float

    def is_valid_sim_agent(self, track: scenario_pb2.Track) -> bool:
        """True for a track valid at the current step: it must be simulated."""
        return len(track.states) > self.current_time_index and track.states[self.current_time_index].valid


def get_submission_config(challenge_type: ChallengeType = ChallengeType.SIM_AGENTS) -> SubmissionConfig:
    """The submission config of a challenge."""
    spec = challenges.spec(challenge_type)
    return SubmissionConfig(current_time_index=spec.current_time_index, n_simulation_steps=spec.num_simulation_steps,
                            n_rollouts=spec.num_rollouts, step_duration_seconds=spec.step_seconds)


def get_sim_agent_ids(scenario: scenario_pb2.Scenario,
                      challenge_type: ChallengeType = ChallengeType.SIM_AGENTS) -> list[int]:
    """Ids of the objects to simulate (valid at the current step), in track order."""
    challenges.as_challenge(challenge_type)
    return challenges.sim_agent_ids(scenario).tolist()


def get_evaluation_sim_agent_ids(scenario: scenario_pb2.Scenario,
                                 challenge_type: ChallengeType = ChallengeType.SIM_AGENTS) -> list[int]:
    """Ids of the evaluated objects: sorted SDC and tracks_to_predict (sim agents), every sim agent (scenario gen)."""
    return challenges.evaluated_ids(challenges.sim_agent_ids(scenario), challenges.predicted_ids(scenario),
                                    challenge_type).tolist()


def _raise_first_error(findings: Sequence, what: str) -> None:
    errors = [f for f in findings if f.severity == "error"]
    if errors:
        more = f" (and {len(errors) - 1} more problem(s))" if len(errors) > 1 else ""
        raise ValueError(f"invalid {what}: {errors[0].message}{more}")


def validate_joint_scene(joint_scene: sim_agents_submission_pb2.JointScene, original_scenario: scenario_pb2.Scenario,
                         challenge_type: ChallengeType = ChallengeType.SIM_AGENTS) -> None:
    """Raises ValueError unless the joint scene holds exactly the sim agents, each with the challenge's
    number of finite values per field (and box sizes and a type for scenario gen)."""
    from wosac_eval.validate import rules

    rollouts = sim_agents_submission_pb2.ScenarioRollouts(scenario_id=original_scenario.scenario_id,
                                                          joint_scenes=[joint_scene])
    findings = rules.check_scenario_rollouts(rollouts, challenges.sim_agent_ids(original_scenario),
                                             challenge=challenge_type, n_rollouts=1)
    _raise_first_error(findings, "JointScene")


def validate_scenario_rollouts(scenario_rollouts: sim_agents_submission_pb2.ScenarioRollouts,
                               original_scenario: scenario_pb2.Scenario,
                               challenge_type: ChallengeType = ChallengeType.SIM_AGENTS) -> None:
    """Raises ValueError unless the rollouts are valid for the scenario: a scenario_id, 32 joint scenes,
    each valid as in `validate_joint_scene`."""
    from wosac_eval.validate import rules

    if not scenario_rollouts.HasField("scenario_id"):
        raise ValueError("invalid ScenarioRollouts: the scenario_id field is missing")
    findings = rules.check_scenario_rollouts(scenario_rollouts, challenges.sim_agent_ids(original_scenario),
                                             challenge=challenge_type)
    _raise_first_error(findings, "ScenarioRollouts")
