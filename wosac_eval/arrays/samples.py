"""The log and the rollouts laid out as the official features see them (the official converters).

One batch of samples per scenario: sample 0 is the log, samples 1..32 the
rollouts. Every sample holds all 91 steps of every simulated object, evaluated
objects first, in the official order:

- Sim agents: history (steps 0..10) and box sizes from the log (sizes frozen
  at the current step for the future), the submitted future after it; the
  log sample keeps the log's validity, rollouts are valid at every future step.
- Scenario gen: all 91 steps, box sizes and object types from the submission
  (the log sample: the logged values, copied whatever their validity, as the
  official `scenario_to_joint_scene` does); every step of every object counts
  as valid (the log's validity at the current step, repeated), and the log's
  real validity is only reported beside the features.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.scenario import ScenarioArrays
from wosac_eval.arrays.trajectories import ObjectTrajectories, index_of_ids, stack_samples

_F = np.float32
_POSITIONS = ("x", "y", "z", "heading")
_SIZES = ("length", "width", "height")


@dataclasses.dataclass(frozen=True)
class SampleBatch:
    """The log followed by the rollouts of one scenario.

    Attributes:
      trajectories: `(num_samples, num_objects, 91)`, evaluated objects first;
        `object_id` and `object_type` are `(num_samples, num_objects)`.
      feature_valid: bool `(num_samples, num_evaluated, 91)`, the validity
        reported with the features (the log's for the log sample).
      evaluated_ids: int64 `(num_evaluated,)`.
      spec: the challenge's spec (which steps are reported, whether ADE is defined).
      num_log_samples: samples before the rollouts (1).
    """

    trajectories: ObjectTrajectories
    feature_valid: np.ndarray
    evaluated_ids: np.ndarray
    spec: challenges.ChallengeSpec
    num_log_samples: int = 1

    @property
    def num_evaluated(self) -> int:
        return int(self.evaluated_ids.shape[0])


def official_object_order(scene_ids: np.ndarray, evaluated_ids: np.ndarray) -> np.ndarray:
    """Evaluated ids, then the other ids in the order the official code visits them.

    The official code lists the non-evaluated agents by iterating a Python set
    difference; that order decides which values land in the trailing partial
    packet of vectorised ops (and ties between equidistant objects), so it is
    reproduced with the same set operations on the same integers.
    """
    others = {int(i) for i in scene_ids} - {int(i) for i in evaluated_ids}
    return np.array([int(i) for i in evaluated_ids] + list(others), dtype=np.int64)


def _official_orders(object_ids: np.ndarray, evaluated_ids: np.ndarray) -> np.ndarray:
    """`official_object_order` of each rollout's ids `(num_rollouts, num_objects)`; rollouts that list
    their agents as the first one does (the usual case) share its order."""
    first = official_object_order(object_ids[0], evaluated_ids)
    if (object_ids == object_ids[0]).all():
        return np.tile(first, (len(object_ids), 1))
    return np.stack([first] + [official_object_order(ids, evaluated_ids) for ids in object_ids[1:]])


def _rollout_columns(rollouts: RolloutArrays, orders: np.ndarray) -> Callable[[Any], Any]:
    """A gather `(num_rollouts, num_objects, ...) -> (num_rollouts, len(order), ...)` per rollout's order."""
    if (rollouts.object_id == rollouts.object_id[0]).all() and (orders == orders[0]).all():
        cols = index_of_ids(rollouts.object_id[0], orders[0])[None]  # usually every rollout lists the same
    else:
        cols = np.stack([index_of_ids(ids, order) for ids, order in zip(rollouts.object_id, orders)])
    if (cols == cols[0]).all():
        if (cols[0] == np.arange(cols.shape[1])).all():
            return lambda a: a
        return lambda a: a[:, cols[0]]
    return lambda a: np.take_along_axis(a, cols.reshape(cols.shape + (1,) * (a.ndim - 2)), axis=1)


def _sim_agents_composite(
    scenario: ScenarioArrays, order: np.ndarray, future: dict, future_valid: np.ndarray
) -> ObjectTrajectories:
    """History from the log, future from `future`, sizes frozen at the current step.

    Args:
      order: int64 `(num_samples, num_objects)`, object ids per sample.
      future: x, y, z, heading float32 `(num_samples, num_objects, 80)`.
      future_valid: bool `(num_samples, num_objects, 80)`.
    """
    log, now = scenario.log, challenges.CURRENT_TIME_INDEX
    rows = index_of_ids(log.object_id, order.reshape(-1)).reshape(order.shape)
    n_future = future["x"].shape[-1]

    def history(a: np.ndarray) -> np.ndarray:
        return a[rows][..., : now + 1]

    def frozen(a: np.ndarray) -> np.ndarray:
        return np.concatenate([history(a), np.repeat(a[rows][..., now : now + 1], n_future, axis=-1)], axis=-1)

    return ObjectTrajectories(
        **{f: np.concatenate([history(getattr(log, f)), future[f].astype(_F)], axis=-1) for f in _POSITIONS},
        **{f: frozen(getattr(log, f)) for f in _SIZES},
        valid=np.concatenate([history(log.valid), future_valid], axis=-1),
        object_id=order,
        object_type=log.object_type[rows],
    )


def log_sample(
    scenario: ScenarioArrays, challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS
) -> tuple[Any, np.ndarray]:
    """(trajectories `(1, num_objects, 91)`, feature validity `(1, num_evaluated, 91)`) of the log."""
    spec = challenges.spec(challenge)
    evaluated = scenario.evaluated_ids(spec)
    order = official_object_order(scenario.sim_agent_ids, evaluated)
    log = scenario.log.take_ids(order)
    feature_valid = log.valid[None, : len(evaluated)]
    if spec.submits_boxes:
        # The logged values become a joint scene, valid wherever the object is valid now.
        logged = {f: getattr(log, f)[None] for f in _POSITIONS + _SIZES}
        now_valid = np.repeat(log.valid[:, challenges.CURRENT_TIME_INDEX, None], log.num_steps, axis=-1)
        return ObjectTrajectories(
            **logged, valid=now_valid[None], object_id=order[None], object_type=log.object_type[None]
        ), feature_valid
    future = spec.simulated_steps
    traj = _sim_agents_composite(
        scenario, order[None], {f: getattr(log, f)[None, :, future] for f in _POSITIONS}, log.valid[None, :, future]
    )
    return traj, feature_valid


def rollout_samples(
    scenario: ScenarioArrays,
    rollouts: RolloutArrays,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    with_log: bool = False,
) -> tuple[Any, np.ndarray]:
    """(trajectories `(num_rollouts, num_objects, 91)`, feature validity `(num_rollouts, num_evaluated, 91)`);
    with `with_log`, the log's sample first (`log_sample`; one composite for all samples, sim agents)."""
    spec = challenges.spec(challenge)
    evaluated = scenario.evaluated_ids(spec)
    orders = _official_orders(rollouts.object_id, evaluated)
    take = _rollout_columns(rollouts, orders)
    positions = {f: take(getattr(rollouts, f)) for f in _POSITIONS}
    if spec.submits_boxes:
        if not rollouts.has_boxes:
            raise ValueError(
                f"scenario {rollouts.scenario_id}: the {spec.challenge} challenge needs the "
                f"submitted box sizes and object types (read with rollout_arrays(..., challenge))"
            )
        rows = index_of_ids(scenario.log.object_id, orders.reshape(-1)).reshape(orders.shape)
        # Valid wherever the logged object is valid now: every sim agent, at every step.
        valid = np.repeat(
            scenario.log.valid[rows, challenges.CURRENT_TIME_INDEX][..., None], rollouts.num_steps, axis=-1
        )
        traj = ObjectTrajectories(
            **positions,
            **{f: take(getattr(rollouts, f)) for f in _SIZES},
            valid=valid,
            object_id=orders,
            # No submitted types: TYPE_UNSET, as the official scores an unset object_type.
            object_type=take(rollouts.object_type)
            if rollouts.object_type is not None
            else np.zeros(orders.shape, dtype=np.int32),
        )
        if with_log:
            log, log_valid = log_sample(scenario, spec)
            return stack_samples([log, traj]), np.concatenate([log_valid, traj.valid[:, : len(evaluated)]])
    else:
        valid = np.ones(positions["x"].shape, dtype=bool)
        if with_log:  # the log's future as one more rollout in front: the same composite as `log_sample`'s
            order = official_object_order(scenario.sim_agent_ids, evaluated)
            log, future = scenario.log.take_ids(order), spec.simulated_steps
            orders = np.concatenate([order[None], orders])
            positions = {f: np.concatenate([getattr(log, f)[None, :, future], positions[f]]) for f in _POSITIONS}
            valid = np.concatenate([log.valid[None, :, future], valid])
        traj = _sim_agents_composite(scenario, orders, positions, valid)
    return traj, traj.valid[:, : len(evaluated)]


def sample_batch(
    scenario: ScenarioArrays,
    rollouts: RolloutArrays,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
) -> SampleBatch:
    """The log as sample 0, then one sample per rollout."""
    spec = challenges.spec(challenge)
    if rollouts.num_steps != spec.num_simulation_steps:
        raise ValueError(
            f"scenario {rollouts.scenario_id}: rollouts have {rollouts.num_steps} steps, the "
            f"{spec.challenge} challenge expects {spec.num_simulation_steps}"
        )
    trajectories, feature_valid = rollout_samples(scenario, rollouts, spec, with_log=True)
    return SampleBatch(
        trajectories=trajectories.validate(),
        feature_valid=feature_valid,
        evaluated_ids=scenario.evaluated_ids(spec),
        spec=spec,
    )
