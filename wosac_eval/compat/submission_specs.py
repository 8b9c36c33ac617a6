"""`waymo_open_dataset.utils.sim_agents.submission_specs`, without TensorFlow.

`ChallengeType` is `wosac_eval.Challenge` (the same values, "sim_agents" and
"scenario_gen"); the validators raise `ValueError` for exactly what the
official ones refuse (a missing scenario_id, a wrong number of joint scenes, a
position or heading of the wrong length, an object that is not a sim agent, a
sim agent missing), with wosac-eval's precise messages. What the official
accepts they accept too, even where `wosac-eval validate` warns or refuses
(non-finite values, repeated objects, scenario-gen box sizes and types): a
program written for the official package behaves the same.
"""

from __future__ import annotations

import dataclasses
from typing import Any

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
    return SubmissionConfig(
        current_time_index=spec.current_time_index,
        n_simulation_steps=spec.num_simulation_steps,
        n_rollouts=spec.num_rollouts,
        step_duration_seconds=spec.step_seconds,
    )


def get_sim_agent_ids(
    scenario: scenario_pb2.Scenario, challenge_type: ChallengeType = ChallengeType.SIM_AGENTS
) -> list[int]:
    """Ids of the objects to simulate (valid at the current step), in track order."""
    challenges.as_challenge(challenge_type)
    return challenges.sim_agent_ids(scenario).tolist()


def get_evaluation_sim_agent_ids(
    scenario: scenario_pb2.Scenario, challenge_type: ChallengeType = ChallengeType.SIM_AGENTS
) -> list[int]:
    """Ids of the evaluated objects: sorted SDC and tracks_to_predict (sim agents), every sim agent (scenario gen)."""
    return challenges.evaluated_ids(
        challenges.sim_agent_ids(scenario), challenges.predicted_ids(scenario), challenge_type
    ).tolist()


# Findings of `validate.rules` that the official validators refuse as well; the others are wosac-eval's
# stricter checks, which the official validators let through.
_OFFICIAL_REFUSALS = ("rollouts.wrong_count", "rollouts.missing_sim_agents", "rollouts.extra_objects")
_CHECKED_FIELDS = ("center_x", "center_y", "center_z", "heading")  # the official checks only these lengths


def _refused_by_official(finding: Any, sim_agent_ids: Any) -> bool:
    if finding.severity != "error":
        return False
    if finding.code == "rollouts.wrong_length":
        return finding.field in _CHECKED_FIELDS
    if finding.code == "rollouts.missing_object_id":  # an unset id reads as 0: refused unless 0 is a sim agent
        return 0 not in sim_agent_ids
    return finding.code in _OFFICIAL_REFUSALS


def _raise_official_refusal(
    rollouts: sim_agents_submission_pb2.ScenarioRollouts,
    scenario: scenario_pb2.Scenario,
    challenge_type: Any,
    what: str,
    n_rollouts: int | None = None,
) -> None:
    """ValueError naming the first of the problems the official validator refuses, if any."""
    from wosac_eval.validate import rules  # loads numba and scipy: 0.46 s the specs alone need not pay

    sim_agent_ids = challenges.sim_agent_ids(scenario)
    options: dict[str, Any] = {} if n_rollouts is None else {"n_rollouts": n_rollouts}
    findings = rules.check_scenario_rollouts(rollouts, sim_agent_ids, challenge=challenge_type, **options)
    refused = [f for f in findings if _refused_by_official(f, set(sim_agent_ids.tolist()))]
    if refused:
        more = f" (and {len(refused) - 1} more problem(s))" if len(refused) > 1 else ""
        raise ValueError(f"invalid {what}: {refused[0].message}{more}")


def validate_joint_scene(
    joint_scene: sim_agents_submission_pb2.JointScene,
    original_scenario: scenario_pb2.Scenario,
    challenge_type: ChallengeType = ChallengeType.SIM_AGENTS,
) -> None:
    """Raises ValueError unless the joint scene holds every sim agent and no other object, each with the
    challenge's number of center_x, center_y, center_z and heading values (what the official checks)."""
    rollouts = sim_agents_submission_pb2.ScenarioRollouts(
        scenario_id=original_scenario.scenario_id, joint_scenes=[joint_scene]
    )
    _raise_official_refusal(rollouts, original_scenario, challenge_type, "JointScene", n_rollouts=1)


def validate_scenario_rollouts(
    scenario_rollouts: sim_agents_submission_pb2.ScenarioRollouts,
    original_scenario: scenario_pb2.Scenario,
    challenge_type: ChallengeType = ChallengeType.SIM_AGENTS,
) -> None:
    """Raises ValueError unless the rollouts have a scenario_id and 32 joint scenes, each valid as in
    `validate_joint_scene`."""
    if not scenario_rollouts.HasField("scenario_id"):
        raise ValueError("invalid ScenarioRollouts: the scenario_id field is missing")
    _raise_official_refusal(scenario_rollouts, original_scenario, challenge_type, "ScenarioRollouts")
