"""All per-step features of one scenario, for the log and the rollouts: the one orchestration.

`per_step_features` computes every feature of a batch of samples (the log as
sample 0, then the rollouts; `arrays.samples`) for numpy and JAX arrays alike.
The features are the entries of `features.registry` (the official ones, then
any registered beside them), each computed by its kernel from one shared
`registry.FeatureContext`. The searches for a nearest thing are delegated to a
strategy: `PrunedSearch` (numpy, compiled loops over proven bounds,
`features.search`) or `DenseSearch` (JAX, fixed shapes, `features.dense`); the
road-edge search takes the boxes and places their corners itself (in its own
order, with the same kernel). The displacement error is computed here.

Feature arrays have shape `(num_samples, num_evaluated, num_steps)`:
the 80 future steps for sim agents, all 91 for scenario gen.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.samples import SampleBatch, sample_batch
from wosac_eval.arrays.scenario import ScenarioArrays
from wosac_eval.features import kinematics, registry, road_edge, traffic_lights
from wosac_eval.features.float32_math import packet_tail
from wosac_eval.features.float32_sums import eigen_sum32
from wosac_eval.features.search import PrunedSearch
from wosac_eval.features.search_strategy import SearchStrategy
from wosac_eval.features.traffic_lights import signals_from
from wosac_eval.features.xp import array_namespace, divide

_F = np.float32
TRAJECTORY_FIELDS = ("x", "y", "z", "heading", "length", "width", "height", "valid")
# The official per-step features (`registry.OFFICIAL_FEATURES`); registered ones follow in `MetricFeatures.extra`.
PER_STEP_FIELDS = registry.OFFICIAL_FEATURE_NAMES


@dataclasses.dataclass(frozen=True)
class MetricFeatures:
    """Features of the evaluated objects (the official `MetricFeatures`).

    Attributes:
      object_id: int64 `(num_evaluated,)`.
      object_type: int32 `(num_samples, num_evaluated)`.
      valid: bool `(num_samples, num_evaluated, num_steps)`.
      average_displacement_error: float32 `(num_samples, num_evaluated)`.
      linear_speed, linear_acceleration, angular_speed, angular_acceleration,
      distance_to_nearest_object, time_to_collision, distance_to_road_edge:
        float32 `(num_samples, num_evaluated, num_steps)`.
      collision_per_step, offroad_per_step, traffic_light_violation_per_step:
        bool `(num_samples, num_evaluated, num_steps)`.
      extra: the features registered beside the official ones (`features.registry.register`), by
        name, `(num_samples, num_evaluated, num_steps)` each; empty without any.
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
    extra: dict = dataclasses.field(default_factory=dict)

    def samples(self, rows: slice) -> MetricFeatures:
        """The given samples (`object_id` is shared by all samples)."""
        return MetricFeatures(
            **{
                f.name: getattr(self, f.name) if f.name == "object_id" else getattr(self, f.name)[rows]
                for f in dataclasses.fields(self)
                if f.name != "extra"
            },
            extra={k: v[rows] for k, v in self.extra.items()},
        )

    def feature(self, name: str) -> Any:
        """A per-step feature by name: an official field or a registered one."""
        return self.extra[name] if name in self.extra else getattr(self, name)

    def as_dict(self) -> dict:
        """Every field but `extra`, and the registered features, by name (see `from_dict`)."""
        return {**{f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "extra"}, **self.extra}

    @classmethod
    def from_dict(cls, values: dict) -> MetricFeatures:
        """The fields of `values`; the names that are not fields go to `extra`."""
        names = {f.name for f in dataclasses.fields(cls)} - {"extra"}
        return cls(
            **{k: v for k, v in values.items() if k in names}, extra={k: v for k, v in values.items() if k not in names}
        )


@dataclasses.dataclass(frozen=True)
class FeatureLayout:
    """The static facts of one feature computation (hashable: a compile-time constant under jit).

    Attributes:
      num_evaluated: evaluated objects, laid out first.
      first_step: the first reported step (11 for sim agents, 0 for scenario gen).
      seconds_per_step: 0.1.
      displacement: the displacement error is measured against sample 0 (the
        log; sim agents), else it is 0 (scenario gen: no object-to-log match).
    """

    num_evaluated: int
    first_step: int
    seconds_per_step: float
    displacement: bool

    @property
    def reported(self) -> slice:
        return slice(self.first_step, None)

    @property
    def first_red_light_step(self) -> int:
        """A crossing is found between a step and the one before: start one step early where there is one."""
        return max(self.first_step - 1, 0)


def feature_layout(spec: challenges.ChallengeSpec, num_evaluated: int) -> FeatureLayout:
    return FeatureLayout(
        num_evaluated=num_evaluated,
        first_step=spec.first_simulated_step,
        seconds_per_step=spec.step_seconds,
        displacement=not spec.evaluates_all_agents,
    )


def official_tails(num_objects: int, num_evaluated: int, num_steps: int, first_step: int) -> dict:
    """Trailing-packet masks of the official sin/cos ops, for the real (unpadded) shapes.

    Returns:
      heading_tail bool `(num_objects, reported steps)`, ego_tail bool
      `(reported steps, num_evaluated, 1)`, pair_tail bool `(reported steps, num_evaluated, num_objects)`.
    """
    reported = slice(first_step, None)
    return {
        "heading_tail": packet_tail((num_objects, num_steps))[:, reported],
        "ego_tail": packet_tail((num_steps, num_evaluated, 1))[reported],
        "pair_tail": packet_tail((num_steps, num_evaluated, num_objects))[reported],
    }


def average_displacement_error(x: Any, y: Any, z: Any, log_valid: Any, num_evaluated: int) -> Any:
    """Mean 3D distance to sample 0 (the log) over the log's valid steps, float32 `(num_samples, num_evaluated)`.

    Summed in the official order (`eigen_sum32`), so it is bit-identical to
    the official value.

    Args:
      x, y, z: float32 `(num_samples, num_objects, num_steps)`.
      log_valid: bool `(num_evaluated, num_steps)`.
    """
    xp = array_namespace(x, log_valid)
    e = slice(0, num_evaluated)
    displacement = kinematics.displacement_error(x[:, e], y[:, e], z[:, e], x[:1, e], y[:1, e], z[:1, e])
    total = eigen_sum32(xp.where(log_valid, displacement, _F(0)))
    return divide(total, log_valid.sum(axis=-1).astype(_F))


def per_step_features(
    t: dict,
    layout: FeatureLayout,
    search: SearchStrategy,
    tails: dict,
    features: tuple[registry.Feature, ...] | None = None,
) -> dict:
    """Every per-step feature of the evaluated objects, for every sample.

    Args:
      t: x, y, z, heading, length, width, height float32 and valid bool, each
        `(num_samples, num_objects, num_steps)`, evaluated objects first.
      search: the searches over the scenario's map (`PrunedSearch`, `DenseSearch` or `HostSearch`).
      tails: `official_tails` of the real shapes.
      features: the registry's entries to compute (default `registry.features()`: the official ones
        and those registered).
    Returns:
      dict of each feature `(num_samples, num_evaluated, reported steps)`, in registry order,
      and average_displacement_error `(num_samples, num_evaluated)`.
    """
    features = registry.features() if features is None else features
    context = registry.FeatureContext(t, layout, search, tails, features)
    out = {f.name: context[f.name] for f in features}
    xp, n_eval = context.xp, layout.num_evaluated
    if layout.displacement:
        out["average_displacement_error"] = average_displacement_error(
            t["x"], t["y"], t["z"], t["valid"][0, :n_eval], n_eval
        )
    else:
        out["average_displacement_error"] = xp.zeros(t["x"].shape[:1] + (n_eval,), _F)
    return out


def metric_features(batch: SampleBatch, per_step: dict) -> tuple[MetricFeatures, MetricFeatures]:
    """(log features with one sample, simulated features with one sample per rollout).

    Args:
      per_step: `per_step_features` of the batch, unpadded, as numpy arrays.
    """
    e = slice(0, batch.num_evaluated)
    reported = slice(batch.spec.first_simulated_step, None)
    both = MetricFeatures.from_dict(
        {
            "object_id": batch.evaluated_ids,
            "object_type": np.asarray(batch.trajectories.object_type[:, e], np.int32),
            "valid": batch.feature_valid[..., reported],
            **{k: np.asarray(v) for k, v in per_step.items()},
        }
    )
    n_log = batch.num_log_samples
    return both.samples(slice(0, n_log)), both.samples(slice(n_log, None))


@dataclasses.dataclass(frozen=True)
class MapContext:
    """Map structures built once per scenario and shared by all samples."""

    road_edges: road_edge.SegmentTable
    lanes: traffic_lights.LaneTable | None


def map_context(scenario: ScenarioArrays) -> MapContext:
    return MapContext(
        road_edges=road_edge.build_segment_table(scenario.road_edges),
        lanes=traffic_lights.build_lane_table(scenario.lanes, scenario.lane_ids),
    )


def trajectory_arrays(batch: SampleBatch) -> dict:
    """The batch's trajectories as the dict `per_step_features` takes."""
    return {f: getattr(batch.trajectories, f) for f in TRAJECTORY_FIELDS}


def scenario_features(
    scenario: ScenarioArrays,
    rollouts: RolloutArrays,
    context: MapContext | None = None,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
) -> tuple[MetricFeatures, MetricFeatures]:
    """(log features, simulated features) of one scenario, with the numpy (pruned) search.

    The log is computed as one more sample beside the rollouts: every kernel
    treats samples independently, and one call shares the map searches.
    """
    return batch_features(scenario, sample_batch(scenario, rollouts, challenge), context)


def batch_features(
    scenario: ScenarioArrays, batch: SampleBatch, context: MapContext | None = None
) -> tuple[MetricFeatures, MetricFeatures]:
    """(log features, simulated features) of a batch of samples of the scenario (`arrays.samples`),
    with the numpy (pruned) search; the first `batch.num_log_samples` samples are the log's."""
    layout = feature_layout(batch.spec, batch.num_evaluated)
    context = context or map_context(scenario)
    search = PrunedSearch(
        context.road_edges, context.lanes, signals_from(scenario.signals, layout.first_red_light_step)
    )
    traj = batch.trajectories
    tails = official_tails(traj.num_objects, batch.num_evaluated, traj.num_steps, layout.first_step)
    # NaN and inf in a submission are scored as given, as officially: they spread without warnings.
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        return metric_features(batch, per_step_features(trajectory_arrays(batch), layout, search, tails))
