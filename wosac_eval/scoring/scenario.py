"""Scoring one scenario: messages (or arrays) in, the official `SimAgentMetrics` fields out.

parse -> arrays (`arrays.samples`) -> features (`features.metric_features`,
numpy or JAX) -> metrics (`metrics.scenario_metrics`), for either challenge.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.analysis.by_object_type import by_object_type
from wosac_eval.analysis.criticality_scores import scenario_criticality
from wosac_eval.analysis.driving_scores import driving_scores
from wosac_eval.arrays.object_types import SHORT_NAMES
from wosac_eval.arrays.rollouts import RolloutArrays, rollout_arrays
from wosac_eval.arrays.scenario import ScenarioArrays, scenario_arrays
from wosac_eval.extras import check_backend
from wosac_eval.features.metric_features import MapContext, MetricFeatures, map_context, scenario_features
from wosac_eval.metrics.config import SimAgentMetricsConfig, config_name_for, load_config
from wosac_eval.metrics.per_object import EVENTS, PerObjectMetrics, per_object_metrics
from wosac_eval.metrics.registry import LIKELIHOOD_FIELDS
from wosac_eval.metrics.scenario_metrics import metric_log_likelihoods, scenario_metrics
from wosac_eval.options import Backend
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2

if TYPE_CHECKING:  # the jax extra: loaded for the jax backend alone (in the functions that use it)
    from wosac_eval.backends.jax_backend import PreparedScenario

PathLike = str | os.PathLike
ConfigLike = str | PathLike | SimAgentMetricsConfig | None


def resolve_config(config: ConfigLike, challenge: challenges.ChallengeLike) -> SimAgentMetricsConfig:
    """A config message from a preset name, a textproto path or a message; None: the challenge's default."""
    if isinstance(config, SimAgentMetricsConfig):
        return config
    return load_config(config_name_for(challenge, config))


def scenario_inputs(
    scenario: scenario_pb2.Scenario | ScenarioArrays,
    rollouts: sim_agents_submission_pb2.ScenarioRollouts | RolloutArrays,
    challenge: challenges.ChallengeLike,
) -> tuple[ScenarioArrays, RolloutArrays]:
    """The arrays of a (scenario, rollouts) pair, checked to belong together."""
    arrays = scenario if isinstance(scenario, ScenarioArrays) else scenario_arrays(scenario)
    if rollouts.scenario_id != arrays.scenario_id:
        raise ValueError(f"rollouts are for scenario {rollouts.scenario_id!r}, not {arrays.scenario_id!r}")
    if not isinstance(rollouts, RolloutArrays):
        rollouts = rollout_arrays(rollouts, challenge)
    check_rollouts_fit(arrays, rollouts, challenge)
    return arrays, rollouts


def check_rollouts_fit(scenario: ScenarioArrays, rollouts: RolloutArrays, challenge: challenges.ChallengeLike) -> None:
    """The rollouts have the challenge's steps (and boxes) and exactly the scenario's sim agents in every rollout.

    Raises:
      ValueError naming the scenario, rollout and objects at fault (validation reports the same
      for files; this guards arrays and messages given to `score_scenario` directly).
    """
    spec = challenges.spec(challenge)
    sid = scenario.scenario_id
    rollouts.validate()
    if rollouts.num_steps != spec.num_simulation_steps:
        raise ValueError(
            f"scenario {sid}: rollouts have {rollouts.num_steps} steps, the {spec.challenge} challenge "
            f"needs {spec.num_simulation_steps}"
        )
    if rollouts.num_rollouts < 1:  # any count is scored, as the official code does; submissions need 32
        raise ValueError(f"scenario {sid}: no rollouts")
    if spec.submits_boxes and not rollouts.has_boxes:
        raise ValueError(
            f"scenario {sid}: the {spec.challenge} challenge needs box sizes (length, width, height, "
            f"one per step); without them the official scorer fails on the scenario too"
        )
    expected = np.sort(scenario.sim_agent_ids)
    ids = np.sort(rollouts.object_id, axis=1)
    if ids.shape[1] != expected.size:
        bad = np.arange(rollouts.num_rollouts)
    else:
        bad = np.flatnonzero(~(ids == expected).all(axis=1))
    if bad.size:
        r = int(bad[0])
        missing = np.setdiff1d(expected, rollouts.object_id[r])
        extra = np.setdiff1d(rollouts.object_id[r], expected)
        raise ValueError(
            f"scenario {sid} rollout {r}: the rollouts must hold exactly the {expected.size} sim agents "
            f"(objects valid at step 10): missing {missing.tolist()}, not sim agents {extra.tolist()}"
        )


def unscorable(scenario_id: str, error: Exception) -> ValueError:
    # e.g. a scenario without road edges, or rollouts missing an evaluated object
    return ValueError(f"scenario {scenario_id}: cannot be scored: {error}")


def scenario_analysis(
    config: SimAgentMetricsConfig,
    scenario: ScenarioArrays,
    rollouts: RolloutArrays,
    log: MetricFeatures,
    sim: MetricFeatures,
    log_likelihoods: dict,
    context: MapContext,
    criticality: dict | None = None,
) -> dict:
    """What a result row carries beside the official metrics, from the same features.

    Returns:
      {"criticality": the scene's heuristic criticality (`analysis.criticality_scores.scene_criticality`; the
      result's assembly adds the rarity), "driving": the SDC's driving scores (or None),
      "by_object_type": the metrics per object type}. `criticality`: the scene's, when computed already.
    """
    if criticality is None:
        criticality = scenario_criticality(scenario, context)
    return {
        "criticality": criticality,
        "driving": driving_scores(scenario, rollouts, sim),
        "by_object_type": by_object_type(config, log, sim, log_likelihoods),
    }


def object_records(scenario_id: str, values: PerObjectMetrics) -> list[dict]:
    """A scene's per-object values (`metrics.per_object.PerObjectMetrics`) as JSON-ready records, one per
    evaluated object in the official order: `scenario_id`, `object_id`, `object_type` (vehicle, pedestrian,
    cyclist or other), every likelihood field (null where the object has no counted sample) and its
    `<metric>_count` (the object's weight in the scene's field), `num_rollouts`, and per event (collision,
    offroad, traffic_light_violation) `<event>_rollouts` (rollouts where the object has it) and
    `<event>_first_step` (its earliest step over the rollouts, null if none)."""
    likelihood = {f: values.likelihood[f].astype(np.float64).tolist() for f in LIKELIHOOD_FIELDS}
    count = {f: values.count[f].tolist() for f in LIKELIHOOD_FIELDS}
    flagged = {e: values.flags[e].sum(axis=0).tolist() for e in EVENTS}
    first = {
        e: np.where(values.flags[e], values.first_step[e], np.iinfo(np.int32).max).min(axis=0).tolist() for e in EVENTS
    }
    num_rollouts = int(next(iter(values.flags.values())).shape[0])
    records = []
    for i, (object_id, kind) in enumerate(zip(values.object_id.tolist(), values.object_type.tolist())):
        record = {"scenario_id": scenario_id, "object_id": object_id, "object_type": SHORT_NAMES.get(kind, "other")}
        for f in LIKELIHOOD_FIELDS:
            value = likelihood[f][i]
            record[f] = None if value != value else value  # NaN: no counted sample
            record[f.removesuffix("_likelihood") + "_count"] = count[f][i]
        record["num_rollouts"] = num_rollouts
        for e in EVENTS:
            record[f"{e}_rollouts"] = flagged[e][i]
            record[f"{e}_first_step"] = first[e][i] if flagged[e][i] else None
        records.append(record)
    return records


def _row(
    config: SimAgentMetricsConfig,
    arrays: ScenarioArrays,
    rollout: RolloutArrays,
    context: Any,
    features: tuple,
    analysis: bool,
    criticality: dict | None = None,
    per_object: bool = False,
) -> dict:
    """A result row from the scene's (log, simulated) `features`, with the analysis and the per-object
    values where asked."""
    log, sim = features
    lls = metric_log_likelihoods(config, log, sim)
    row = {"scenario_id": arrays.scenario_id, **scenario_metrics(config, log, sim, lls)}
    if analysis:
        row.update(scenario_analysis(config, arrays, rollout, log, sim, lls, context, criticality))
    if per_object:
        row["objects"] = object_records(arrays.scenario_id, per_object_metrics(config, log, sim, lls))
    return row


def score_scenario(
    scenario: scenario_pb2.Scenario | ScenarioArrays,
    rollouts: sim_agents_submission_pb2.ScenarioRollouts | RolloutArrays,
    config: ConfigLike = None,
    *,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    backend: str = "numpy",
    analysis: bool = False,
    per_object: bool = False,
    criticality: dict | None = None,
) -> dict:
    """Official `SimAgentMetrics` fields of one scenario, plus its `scenario_id`.

    Args:
      scenario: the logged `Scenario` (or its `ScenarioArrays`).
      rollouts: the 32 simulated joint scenes for it (a `ScenarioRollouts`, or `RolloutArrays`).
      config: a preset name, a textproto path or a `SimAgentMetricsConfig`;
        None: the challenge's current leaderboard config.
      challenge: "sim_agents" (80 future steps, SDC + tracks_to_predict
        evaluated) or "scenario_gen" (91 steps with boxes, every sim agent evaluated).
      backend: "numpy" or "jax" (needs the `jax` extra); same results.
      analysis: add the scene's criticality (without rarity), the SDC's driving scores and the
        metrics per object type (`scenario_analysis`), as `score_submission` does.
      per_object: add `objects`, the values of every evaluated object (`object_records`), as
        `score_submission(per_object=True)` streams them.
      criticality: with `analysis`, the scene's criticality when known already (kept from an earlier run:
        `analysis.criticality_cache`), instead of computing it.
    """
    message, arrays, rollout, context, log, sim = _scored_features(scenario, rollouts, config, challenge, backend)
    return _row(message, arrays, rollout, context, (log, sim), analysis, criticality, per_object=per_object)


def _scored_features(
    scenario: scenario_pb2.Scenario | ScenarioArrays,
    rollouts: RolloutArrays,
    config: ConfigLike,
    challenge: challenges.ChallengeLike,
    backend: str,
) -> Any:
    """What scoring one pair starts from: (config message, arrays, rollouts, map context, log, sim features)."""
    backend = check_backend(backend)
    challenge = challenges.as_challenge(challenge)
    message = resolve_config(config, challenge)
    arrays, rollout = scenario_inputs(scenario, rollouts, challenge)
    try:
        context = map_context(arrays)
        if backend is Backend.JAX:
            from wosac_eval.backends import jax_backend  # the jax extra, loaded for the jax backend alone

            log, sim = jax_backend.scenario_features(arrays, rollout, context, challenge=challenge)
        else:
            log, sim = scenario_features(arrays, rollout, context, challenge=challenge)
    except (ValueError, KeyError) as error:
        raise unscorable(arrays.scenario_id, error) from error
    return message, arrays, rollout, context, log, sim


def score_scenario_per_object(
    scenario: scenario_pb2.Scenario | ScenarioArrays,
    rollouts: sim_agents_submission_pb2.ScenarioRollouts | RolloutArrays,
    config: ConfigLike = None,
    *,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    backend: str = "numpy",
) -> PerObjectMetrics:
    """The values per evaluated object behind `score_scenario`'s fields (same arguments): a
    `metrics.per_object.PerObjectMetrics` (likelihoods and their weights per object, each rollout's
    collision, off-road and red-light flags and first steps)."""
    message, _, _, _, log, sim = _scored_features(scenario, rollouts, config, challenge, backend)
    return per_object_metrics(message, log, sim)


@dataclasses.dataclass(frozen=True)
class JaxItem:
    """A scenario prepared on the host for the jax backend (a worker's output in the pipelined file path).

    Attributes:
      arrays, rollout, context: the scenario's arrays, rollouts and map context.
      prepared: `jax_backend.PreparedScenario`.
      criticality: the scene's criticality (`scene_criticality`) when the analysis is asked for, else None.
    """

    arrays: ScenarioArrays
    rollout: RolloutArrays
    context: MapContext
    prepared: PreparedScenario
    criticality: dict | None = None


def prepare_jax_item(
    scenario: scenario_pb2.Scenario,
    rollouts: RolloutArrays,
    challenge: challenges.ChallengeLike,
    analysis: bool = False,
    criticality: dict | None = None,
) -> JaxItem:
    """The host part of jax-backend scoring of one pair: arrays, map context, padded-ready inputs (and, with
    `analysis`, the scene's criticality: `criticality` when known already, else computed)."""
    from wosac_eval.backends import jax_backend  # the jax extra, loaded for the jax backend alone

    arrays, rollout = scenario_inputs(scenario, rollouts, challenge)
    try:
        context = map_context(arrays)
        prepared = jax_backend.prepare(arrays, rollout, context, challenge=challenge)
    except (ValueError, KeyError) as error:
        raise unscorable(arrays.scenario_id, error) from error
    if not analysis:
        criticality = None
    elif criticality is None:
        criticality = scenario_criticality(arrays, context)
    return JaxItem(arrays, rollout, context, prepared, criticality)


def score_jax_items(
    items: Iterable[JaxItem],
    config: ConfigLike = None,
    max_batch: int = 8,
    *,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    analysis: bool = False,
    per_object: bool = False,
) -> Iterator[dict]:
    """Rows of a stream of `JaxItem`s, in stream order, the device computing while the host finishes rows.

    Yields each row as soon as it and every earlier one are done (`jax_backend.FeaturePipeline`).
    """
    from wosac_eval.backends import jax_backend  # the jax extra, loaded for the jax backend alone

    config = resolve_config(config, challenges.as_challenge(challenge))
    pipeline = jax_backend.FeaturePipeline(max_batch=max_batch)
    rows: dict[int, dict] = {}
    next_out = 0

    def finish(done: Any) -> None:
        for (index, item), features in done:
            rows[index] = _row(
                config, item.arrays, item.rollout, item.context, features, analysis, item.criticality, per_object
            )

    def ready() -> Iterator[dict]:
        nonlocal next_out
        while next_out in rows:
            yield rows.pop(next_out)
            next_out += 1

    for index, item in enumerate(items):
        finish(pipeline.add((index, item), item.prepared))
        yield from ready()
    finish(pipeline.finish())
    yield from ready()


def score_scenarios_jax(
    pairs: Iterable[tuple[scenario_pb2.Scenario, RolloutArrays]],
    config: ConfigLike = None,
    max_batch: int = 8,
    *,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    analysis: bool = False,
    per_object: bool = False,
) -> list[dict]:
    """`score_scenario` with the jax backend for many (scenario, rollouts) pairs at once.

    Scenarios of the same size bucket share one `vmap`ped call.
    """
    challenge = challenges.as_challenge(challenge)
    items = (prepare_jax_item(scenario, rollouts, challenge, analysis) for scenario, rollouts in pairs)
    return list(
        score_jax_items(items, config, max_batch, challenge=challenge, analysis=analysis, per_object=per_object)
    )
