"""What a picture of one scenario shows: its arrays (map, log), its rollouts, and the metric events where
they start (collisions, off-road and red-light runs, as the official features flag them: the same
per-step features the scores come from). Drawn by `scene_painter`, written by `scene_plot`."""

from __future__ import annotations

import dataclasses

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.scenario import ScenarioArrays, scenario_arrays
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2
from wosac_eval.scoring.scenario import scenario_inputs

# (feature, label, marker, colour) of each event drawn.
EVENT_KINDS = (
    ("collision_per_step", "collision", "X", "#d1242f"),
    ("offroad_per_step", "off-road", "^", "#e36209"),
    ("traffic_light_violation_per_step", "red-light run", "s", "#8250df"),
)


@dataclasses.dataclass(frozen=True)
class SceneEvent:
    """The start of a run of flagged steps of one object in one rollout.

    Attributes:
      kind: "collision", "off-road" or "red-light run".
      rollout, object_id: where.
      step: the logged step index (0..90) the run starts at.
      x, y: the object's simulated centre there.
    """

    kind: str
    rollout: int
    object_id: int
    step: int
    x: float
    y: float


@dataclasses.dataclass(frozen=True)
class SceneView:
    """What a picture of one scenario shows.

    Attributes:
      scenario: the scenario's arrays (map, log).
      rollouts: the simulated rollouts, or None (the log alone).
      challenge: the challenge the rollouts are for.
      events: every event start, in rollout, object, step order.
      evaluated_ids: int64 `(num_evaluated,)`, the objects whose events are flagged.
    """

    scenario: ScenarioArrays
    rollouts: RolloutArrays | None
    challenge: challenges.Challenge
    events: tuple[SceneEvent, ...]
    evaluated_ids: np.ndarray

    @property
    def first_simulated_step(self) -> int:
        """The logged step index of the first simulated value (11 sim agents, 0 scenario gen)."""
        return challenges.spec(self.challenge).first_simulated_step

    def simulated_step(self, step: int) -> int | None:
        """The rollouts' index of a logged step, or None before the simulation starts."""
        k = step - self.first_simulated_step
        return k if self.rollouts is not None and 0 <= k < self.rollouts.num_steps else None

    def event_counts(self) -> dict[str, int]:
        return {label: sum(e.kind == label for e in self.events) for _, label, _, _ in EVENT_KINDS}


def _event_starts(flags: np.ndarray) -> np.ndarray:
    """(sample, object, step) of the first step of every run of True in bool `(num_samples, num_objects, num_steps)`."""
    before = np.concatenate([np.zeros_like(flags[..., :1]), flags[..., :-1]], axis=-1)
    return np.argwhere(flags & ~before)


def scene_view(
    scenario: scenario_pb2.Scenario | ScenarioArrays,
    rollouts: sim_agents_submission_pb2.ScenarioRollouts | RolloutArrays | None = None,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
) -> SceneView:
    """The view of a scenario (a `Scenario` or its arrays) and optionally its rollouts (message or arrays).

    Raises:
      ValueError: the rollouts do not fit the scenario (other scenario, steps, objects).
    """
    challenge = challenges.as_challenge(challenge)
    arrays = scenario if isinstance(scenario, ScenarioArrays) else scenario_arrays(scenario)
    if rollouts is None:
        return SceneView(arrays, None, challenge, (), arrays.evaluated_ids(challenge))
    arrays, rollouts = scenario_inputs(arrays, rollouts, challenge)
    _, sim = scenario_features(arrays, rollouts, challenge=challenge)
    first = challenges.spec(challenge).first_simulated_step
    # Each rollout lists its objects in its own order; events come in the evaluated order.
    position = {
        (r, int(oid)): i for r in range(rollouts.num_rollouts) for i, oid in enumerate(rollouts.object_id[r].tolist())
    }
    events = []
    for feature, label, _, _ in EVENT_KINDS:
        for r, e, k in _event_starts(np.asarray(getattr(sim, feature), dtype=bool)).tolist():
            object_id = int(sim.object_id[e])
            i = position[(r, object_id)]
            events.append(
                SceneEvent(label, r, object_id, first + k, float(rollouts.x[r, i, k]), float(rollouts.y[r, i, k]))
            )
    events.sort(key=lambda ev: (ev.rollout, ev.object_id, ev.step))
    return SceneView(arrays, rollouts, challenge, tuple(events), np.asarray(sim.object_id))
