"""`waymo_open_dataset.wdl_limited.sim_agents_metrics.metric_features`, without TensorFlow.

    log_features, sim_features = metric_features.compute_scenario_rollouts_features(
        scenario, scenario_rollouts, submission_specs.ChallengeType.SIM_AGENTS)
    scenario_metrics = metrics.compute_scenario_metrics_for_features_bundle(
        config, scenario.scenario_id, log_features, sim_features)

The features are wosac-eval's (`wosac_eval.features.metric_features`),
bit-identical to the official ones, as numpy arrays with the official shapes
and dtypes where the official ones are TensorFlow tensors (answering
`.numpy()` as those do: `compat._arrays.CompatArray`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.samples import sample_batch
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.arrays.trajectories import index_of_ids
from wosac_eval.compat._arrays import compat_array
from wosac_eval.compat.submission_specs import ChallengeType
from wosac_eval.features import metric_features as _features
from wosac_eval.protos import map_pb2, scenario_pb2, sim_agents_submission_pb2

# The official module's private aliases, which some client programs read.
_ChallengeType = ChallengeType
_LaneType = map_pb2.LaneCenter.LaneType


@dataclasses.dataclass(frozen=True)
class MetricFeatures:
    """The features the metrics are computed from, for the evaluated objects.

    `n_samples` is 1 for the log and for one joint scene, the number of
    rollouts for `compute_scenario_rollouts_features`'s simulated features;
    `n_steps` is 80 (sim agents: the simulated future) or 91 (scenario gen).

    Attributes:
      object_id: int32 `(num_objects,)`, shared by all samples.
      object_type: int32 `(num_samples, num_objects)`.
      valid: bool `(num_samples, num_objects, num_steps)`, the steps that count.
      average_displacement_error: float32 `(num_samples, num_objects)`, mean 3D distance to the log over
        its valid steps (0 for scenario gen).
      linear_speed, linear_acceleration, angular_speed, angular_acceleration: float32
        `(num_samples, num_objects, num_steps)`, finite differences (m/s, m/s², rad/s, rad/s²).
      distance_to_nearest_object: float32 `(num_samples, num_objects, num_steps)`, signed, in metres.
      collision_per_step: bool `(num_samples, num_objects, num_steps)`.
      time_to_collision: float32 `(num_samples, num_objects, num_steps)`, seconds, with the object in front.
      distance_to_road_edge: float32 `(num_samples, num_objects, num_steps)`, signed (positive off the road).
      offroad_per_step: bool `(num_samples, num_objects, num_steps)`.
      traffic_light_violation_per_step: bool `(num_samples, num_objects, num_steps)`.
    """

    object_id: np.ndarray
    object_type: np.ndarray
    valid: np.ndarray
    average_displacement_error: np.ndarray
    linear_speed: np.ndarray
    linear_acceleration: np.ndarray
    angular_speed: np.ndarray
    angular_acceleration: np.ndarray
    distance_to_nearest_object: np.ndarray
    collision_per_step: np.ndarray
    time_to_collision: np.ndarray
    distance_to_road_edge: np.ndarray
    offroad_per_step: np.ndarray
    traffic_light_violation_per_step: np.ndarray


def _official(features: _features.MetricFeatures) -> MetricFeatures:
    values = {f.name: compat_array(getattr(features, f.name)) for f in dataclasses.fields(MetricFeatures)}
    ids = values["object_id"]
    if ids.size and (ids.min() < np.iinfo(np.int32).min or ids.max() > np.iinfo(np.int32).max):
        raise ValueError(f"object ids {ids.tolist()} do not fit the official int32 ids")
    values["object_id"] = compat_array(ids.astype(np.int32))
    return MetricFeatures(**values)


def as_internal(features: Any) -> _features.MetricFeatures:
    """Any object with the `MetricFeatures` fields (numpy arrays, or anything `np.asarray` reads, e.g.
    TensorFlow tensors) as wosac-eval's own `MetricFeatures`."""
    fields: dict[str, Any] = {
        f.name: np.asarray(getattr(features, f.name))
        for f in dataclasses.fields(_features.MetricFeatures)
        if f.name != "extra"
    }
    return _features.MetricFeatures(**fields)


def compute_metric_features(
    scenario: scenario_pb2.Scenario,
    joint_scene: sim_agents_submission_pb2.JointScene,
    challenge_type: ChallengeType = ChallengeType.SIM_AGENTS,
    use_log_validity: bool = False,
) -> MetricFeatures:
    """The features of one joint scene (n_samples=1).

    Args:
      scenario: the logged scenario the joint scene continues (sim agents) or replaces (scenario gen).
      joint_scene: one rollout: every sim agent, 80 future steps (sim agents) or 91 steps with box sizes and
        object types (scenario gen).
      challenge_type: the challenge.
      use_log_validity: take validity from the log instead of counting every simulated step as valid
        (the official log features: `converters.scenario_to_joint_scene` with this flag).

    Raises:
      ValueError: the joint scene does not fit the scenario or the challenge.
    """
    challenge = challenges.as_challenge(challenge_type)
    arrays = scenario_arrays(scenario)
    rollouts = rollout_arrays(
        sim_agents_submission_pb2.ScenarioRollouts(scenario_id=scenario.scenario_id, joint_scenes=[joint_scene]),
        challenge,
    )
    try:
        # The log is sample 0 (the displacement error is measured against it), the joint scene sample 1.
        batch = sample_batch(arrays, rollouts, challenge)
        if use_log_validity:
            traj = batch.trajectories
            valid = traj.valid
            if not batch.spec.submits_boxes:  # sim agents: the future is valid where the log is
                rows = index_of_ids(arrays.log.object_id, traj.object_id[1])
                valid = np.concatenate([valid[:1], arrays.log.valid[rows][None]])
            batch = dataclasses.replace(
                batch, trajectories=dataclasses.replace(traj, valid=valid), feature_valid=batch.feature_valid[[0, 0]]
            )
    except KeyError as error:  # an object of the joint scene (or an evaluated one) is missing
        raise ValueError(
            f"scenario {scenario.scenario_id}: the joint scene does not fit the scenario: {error}"
        ) from error
    _, simulated = _features.batch_features(arrays, batch)
    return _official(simulated)


def compute_scenario_rollouts_features(
    scenario: scenario_pb2.Scenario,
    scenario_rollouts: sim_agents_submission_pb2.ScenarioRollouts,
    challenge_type: ChallengeType = ChallengeType.SIM_AGENTS,
) -> tuple[MetricFeatures, MetricFeatures]:
    """(log features with n_samples=1, simulated features with one sample per joint scene).

    The log features are those of the logged scene as a joint scene, with the log's validity.

    Raises:
      ValueError: the rollouts do not fit the scenario or the challenge.
    """
    challenge = challenges.as_challenge(challenge_type)
    try:
        log, simulated = _features.scenario_features(
            scenario_arrays(scenario), rollout_arrays(scenario_rollouts, challenge), challenge=challenge
        )
    except KeyError as error:
        raise ValueError(f"scenario {scenario.scenario_id}: the rollouts do not fit the scenario: {error}") from error
    return _official(log), _official(simulated)
