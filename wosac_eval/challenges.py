"""The two challenges the official metrics serve, and what each asks of a submission.

- Sim Agents (`sim_agents`): 32 rollouts of the 80 future steps (8 s after the
  current step, index 10) of every object valid at the current step; only the
  SDC and the `tracks_to_predict` are evaluated; history, box sizes and object
  types come from the log.
- Scenario Generation (`scenario_gen`): 32 rollouts of all 91 steps (history,
  current, future) of the same objects, with per-step box sizes and the object
  type; every such object is evaluated.

These are facts of the official submission specs (waymo-open-dataset 1.6.7,
`utils/sim_agents/submission_specs.py`); everything below the fronts asks this
module instead of restating them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from wosac_eval.options import Choice

if TYPE_CHECKING:  # the message type alone: the protobuf modules load when a message is parsed
    from wosac_eval.protos import scenario_pb2

CURRENT_TIME_INDEX = 10  # the 11th step is "now"
NUM_LOGGED_STEPS = 91
NUM_ROLLOUTS = 32
STEP_SECONDS = 0.1


class Challenge(Choice):
    """A challenge; its value is the name used on the command line, in results and in the service.

    A front turns what it was given into a member once (`as_challenge`); below it every function passes
    the member on, and a function of the library's public face takes any `ChallengeLike`.
    """

    SIM_AGENTS = "sim_agents"
    SCENARIO_GEN = "scenario_gen"


@dataclasses.dataclass(frozen=True)
class ChallengeSpec:
    """What a submission of one challenge holds and how it is evaluated.

    Attributes:
      challenge: the challenge.
      num_simulation_steps: values per simulated field (80 or 91).
      first_simulated_step: the logged step index of the first submitted value
        (11 or 0); features are reported for these steps only.
      num_rollouts: joint scenes per scenario (32).
      submits_boxes: the submission carries per-step `length`, `width`,
        `height` and the `object_type` (scenario gen), else they come from the log.
      evaluates_all_agents: every sim agent is evaluated (scenario gen), else
        the SDC and the `tracks_to_predict`.
      default_config: the preset of the challenge's current leaderboard.
    """

    challenge: Challenge
    num_simulation_steps: int
    first_simulated_step: int
    submits_boxes: bool
    evaluates_all_agents: bool
    default_config: str
    num_rollouts: int = NUM_ROLLOUTS
    current_time_index: int = CURRENT_TIME_INDEX
    step_seconds: float = STEP_SECONDS

    @property
    def simulated_steps(self) -> slice:
        """The logged steps a submission simulates, and the steps its features are reported for."""
        return slice(self.first_simulated_step, self.first_simulated_step + self.num_simulation_steps)


SPECS = {
    Challenge.SIM_AGENTS: ChallengeSpec(
        Challenge.SIM_AGENTS,
        num_simulation_steps=80,
        first_simulated_step=CURRENT_TIME_INDEX + 1,
        submits_boxes=False,
        evaluates_all_agents=False,
        default_config="2025",
    ),
    Challenge.SCENARIO_GEN: ChallengeSpec(
        Challenge.SCENARIO_GEN,
        num_simulation_steps=91,
        first_simulated_step=0,
        submits_boxes=True,
        evaluates_all_agents=True,
        default_config="scenario_gen_2025",
    ),
}
CHALLENGE_NAMES = tuple(c.value for c in Challenge)
# What names a challenge where a user gives one: the member, its name, its spec, or the official enum.
ChallengeLike = Challenge | str | ChallengeSpec


def as_challenge(value: ChallengeLike) -> Challenge:
    """A `Challenge` from itself, its spec, its name (`sim_agents`), or the official enum's name or value."""
    if isinstance(value, ChallengeSpec):
        return value.challenge
    if isinstance(value, Challenge):
        return value
    name = getattr(value, "value", value)  # the official ChallengeType enum carries the same values
    if isinstance(name, str):
        key = name.strip().lower().replace("-", "_")
        for challenge in Challenge:
            if key in (challenge.value, challenge.name.lower()):
                return challenge
    raise ValueError(f"unknown challenge {value!r}: choose one of {', '.join(CHALLENGE_NAMES)}")


def spec(challenge: ChallengeLike = Challenge.SIM_AGENTS) -> ChallengeSpec:
    """The spec of a challenge (given as in `as_challenge`)."""
    return SPECS[as_challenge(challenge)]


def sim_agent_ids(scenario: scenario_pb2.Scenario) -> np.ndarray:
    """Ids of the tracks valid at the current step, in track order, int64 `(num_objects,)`.

    Both challenges simulate exactly these objects. A track too short to have
    a current step has no valid state there.
    """
    return sim_agents_among(
        [t.id for t in scenario.tracks],
        [len(t.states) > CURRENT_TIME_INDEX and t.states[CURRENT_TIME_INDEX].valid for t in scenario.tracks],
    )


def sim_agents_among(track_ids: ArrayLike, valid_at_current: ArrayLike) -> np.ndarray:
    """`sim_agent_ids` of tracks given as arrays (a message or its wire bytes read alike).

    Args:
      track_ids: int `(num_objects,)`; valid_at_current: bool `(num_objects,)`, false for a track
        without a current step.
    """
    return np.asarray(track_ids, np.int64).reshape(-1)[np.asarray(valid_at_current, bool).reshape(-1)]


def predicted_ids(scenario: scenario_pb2.Scenario) -> np.ndarray:
    """Sorted ids of the SDC and of every `tracks_to_predict` entry, int64 `(num_evaluated,)`."""
    return predicted_among(
        [t.id for t in scenario.tracks], scenario.sdc_track_index, [r.track_index for r in scenario.tracks_to_predict]
    )


def predicted_among(track_ids: ArrayLike, sdc_track_index: int, predicted_track_indices: Iterable[int]) -> np.ndarray:
    """`predicted_ids` of tracks given as arrays: the ids at `sdc_track_index` and at each of the
    `predicted_track_indices`, indexed as the message's repeated field is (from the end when negative;
    IndexError past either end)."""
    ids = np.asarray(track_ids, np.int64).reshape(-1)

    def track_id(index: int, field: str) -> int:
        if not -len(ids) <= int(index) < len(ids):
            raise IndexError(f"{field} {int(index)} is not the index of a track (there are {len(ids)})")
        return int(ids[int(index)])

    found = {track_id(sdc_track_index, "sdc_track_index")}
    found.update(track_id(index, "a tracks_to_predict track_index") for index in predicted_track_indices)
    return np.array(sorted(found), dtype=np.int64)


def evaluated_ids(sim_agents: np.ndarray, predicted: np.ndarray, challenge: ChallengeLike) -> np.ndarray:
    """The evaluated objects, in the official order, int64 `(num_evaluated,)`.

    Sim agents: the sorted SDC and `tracks_to_predict`. Scenario gen: every sim
    agent, in track order (the official code lists them so, unsorted).
    """
    return np.asarray(sim_agents if spec(challenge).evaluates_all_agents else predicted, dtype=np.int64)
