"""Per-object values of a scene: the likelihoods behind its fields, and each rollout's events.

A scene's likelihood field is exp(the mean log-likelihood over its counted samples), exactly as
the official code reduces it, so it is the count-weighted geometric mean of its objects' values:

    field = prod_i likelihood[i] ** (count[i] / sum_j count[j])

where `likelihood[i]` is exp(object i's mean log-likelihood over its own counted samples) and
`count[i]` the number of those samples: its steps under the metric's mask for a time series (speed
and acceleration validity, the log's valid steps, valid vehicle steps for time to collision), 1 for
the per-object indicators (collision, off-road, traffic light: the official code reduces each
object's steps to one flag before the likelihood, and averages the objects' log-likelihoods).
`PerObjectMetrics.scene_likelihood` computes the right-hand side. The log-likelihoods are the scene's
own (`scenario_metrics.metric_log_likelihoods`): nothing is estimated again per object.

Events per rollout and object, as the scene's simulated rates count them: the object collided,
went off road or ran a red light at a step where its log is valid (every object type, as the
official rates count them; the traffic-light likelihood counts vehicles only), so the share of
flagged (rollout, object) pairs is the scene's `simulated_*_rate`.

These are diagnostics beside the official metrics, from the same features; they change no result row.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from wosac_eval.features.metric_features import MetricFeatures
from wosac_eval.metrics.config import SimAgentMetricsConfig
from wosac_eval.metrics.registry import LIKELIHOOD_FIELDS, RATES
from wosac_eval.metrics.scenario_metrics import per_object_likelihoods, validity_masks

# Event name -> the scene's rate that counts it, and the per-step feature it is read from.
EVENTS: dict[str, str] = {rate.feature.removesuffix("_per_step"): rate.name for rate in RATES}
_EVENT_FEATURES = {rate.feature.removesuffix("_per_step"): rate.feature for rate in RATES}


@dataclasses.dataclass(frozen=True)
class PerObjectMetrics:
    """A scene's values per evaluated object, in the official object order (numpy).

    Attributes:
      object_id: int64 `(num_objects,)`, the evaluated objects.
      object_type: int32 `(num_objects,)`, their logged types (`scenario_pb2.Track.ObjectType`).
      likelihood: every likelihood field (`registry.LIKELIHOOD_FIELDS`) -> float32 `(num_objects,)`:
        exp(the object's mean log-likelihood over its counted samples); NaN where it has none.
      count: the same fields -> int32 `(num_objects,)`: its counted samples (its weight in the scene's field).
      flags: event ("collision", "offroad", "traffic_light_violation"; `EVENTS`) -> bool
        `(num_rollouts, num_objects)`: the event happened at a step where the log is valid.
      first_step: the same events -> int32 `(num_rollouts, num_objects)`: the first such step, -1 if
        none. Steps index the rollout's own steps (Sim Agents: 0 is the first of the 80 simulated
        steps, scenario step 11; Scenario Generation: 0 is scenario step 0 of 91).
    """

    object_id: np.ndarray
    object_type: np.ndarray
    likelihood: dict
    count: dict
    flags: dict
    first_step: dict

    @property
    def num_objects(self) -> int:
        return int(self.object_id.size)

    def scene_likelihood(self, field: str) -> float:
        """The count-weighted geometric mean of the objects' values of `field` (float64): the scene's
        field (NaN when no object has a counted sample, as the scene's own field then is)."""
        counts = self.count[field].astype(np.float64)
        total = counts.sum()
        if total == 0:
            return float("nan")
        counted = counts > 0
        log_values = np.log(self.likelihood[field][counted].astype(np.float64))
        return float(np.exp((counts[counted] * log_values).sum() / total))

    def rate(self, event: str) -> float:
        """The share of (rollout, object) pairs with the event: the scene's `EVENTS[event]` rate."""
        return float(self.flags[event].mean(dtype=np.float64))


def event_steps(log: MetricFeatures, sim: MetricFeatures) -> tuple[dict, dict]:
    """(flags, first steps) of every event per rollout and object (see `PerObjectMetrics`), numpy."""
    valid = np.asarray(validity_masks(log)["valid"])
    flags, first = {}, {}
    for event, feature in _EVENT_FEATURES.items():
        per_step = np.asarray(getattr(sim, feature)) & valid
        flags[event] = per_step.any(axis=-1)
        first[event] = np.where(flags[event], per_step.argmax(axis=-1), -1).astype(np.int32)
    return flags, first


def per_object_metrics(
    config: SimAgentMetricsConfig, log: MetricFeatures, sim: MetricFeatures, log_likelihoods: dict | None = None
) -> PerObjectMetrics:
    """A scene's per-object likelihoods, counts and events, from its features (numpy).

    Args:
      config: the metrics config the scene's fields are computed with.
      log, sim: the scene's `MetricFeatures` (`features.metric_features.scenario_features`).
      log_likelihoods: `scenario_metrics.metric_log_likelihoods(config, log, sim)` when computed already
        (`score_scenario` computes them for the scene's row).
    """
    values = per_object_likelihoods(config, log, sim, log_likelihoods)
    flags, first = event_steps(log, sim)
    return PerObjectMetrics(
        object_id=np.asarray(log.object_id, np.int64),
        object_type=np.asarray(log.object_type, np.int32)[0],
        likelihood={f: np.asarray(values[f][0]) for f in LIKELIHOOD_FIELDS},
        count={f: np.asarray(values[f][1]) for f in LIKELIHOOD_FIELDS},
        flags=flags,
        first_step=first,
    )
