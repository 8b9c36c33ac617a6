"""`waymo_open_dataset.wdl_limited.sim_agents_metrics.metrics`, without TensorFlow.

    config = metrics.load_metrics_config(submission_specs.ChallengeType.SIM_AGENTS)
    scenario_metrics = metrics.compute_scenario_metrics_for_bundle(config, scenario, scenario_rollouts)
    aggregate = metrics.aggregate_scenario_metrics([scenario_metrics, ...])
    buckets = metrics.aggregate_metrics_to_buckets(config, aggregate)

The same messages as the official functions (`SimAgentMetrics`,
`SimAgentsBucketedMetrics`), computed by wosac-eval's scorer.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.compat.metric_features import as_internal
from wosac_eval.compat.submission_specs import ChallengeType
from wosac_eval.metrics.config import default_config, load_config
from wosac_eval.metrics.scenario_metrics import bucket_metrics, scenario_metrics
from wosac_eval.protos import scenario_pb2, sim_agents_metrics_pb2, sim_agents_submission_pb2
from wosac_eval.scoring.scenario import score_scenario


def load_metrics_config(
    challenge_type: ChallengeType = ChallengeType.SIM_AGENTS,
) -> sim_agents_metrics_pb2.SimAgentMetricsConfig:
    """The challenge's 2025 config (sim agents, or scenario gen)."""
    return load_config(default_config(challenge_type))


def compute_scenario_metrics_for_bundle(
    config: sim_agents_metrics_pb2.SimAgentMetricsConfig,
    scenario: scenario_pb2.Scenario,
    scenario_rollouts: sim_agents_submission_pb2.ScenarioRollouts,
    challenge_type: ChallengeType = ChallengeType.SIM_AGENTS,
) -> sim_agents_metrics_pb2.SimAgentMetrics:
    """The scenario's metrics as a `SimAgentMetrics` message (likelihoods, meta-metric, ADE, rates)."""
    return sim_agents_metrics_pb2.SimAgentMetrics(
        **score_scenario(scenario, scenario_rollouts, config, challenge=challenge_type)
    )


def aggregate_scenario_metrics(
    all_scenario_metrics: list[sim_agents_metrics_pb2.SimAgentMetrics],
) -> sim_agents_metrics_pb2.SimAgentMetrics:
    """The mean of every field set in the first message, over all messages (the official aggregation)."""
    if not all_scenario_metrics:
        raise ValueError("no scenario metrics to aggregate")
    names = [field.name for field, _ in all_scenario_metrics[0].ListFields() if field.name != "scenario_id"]
    return sim_agents_metrics_pb2.SimAgentMetrics(
        **{name: np.mean([getattr(m, name) for m in all_scenario_metrics]) for name in names}
    )


def aggregate_metrics_to_buckets(
    config: sim_agents_metrics_pb2.SimAgentMetricsConfig, metrics: sim_agents_metrics_pb2.SimAgentMetrics
) -> sim_agents_metrics_pb2.SimAgentsBucketedMetrics:
    """Kinematic, interactive and map-based weighted means of the likelihoods, and the headline figures."""
    values = {
        field.name: getattr(metrics, field.name) for field in metrics.DESCRIPTOR.fields if field.name != "scenario_id"
    }
    return sim_agents_metrics_pb2.SimAgentsBucketedMetrics(**bucket_metrics(config, values))


def compute_scenario_metrics_for_features_bundle(
    config: sim_agents_metrics_pb2.SimAgentMetricsConfig, scenario_id: str, log_features: Any, sim_features: Any
) -> sim_agents_metrics_pb2.SimAgentMetrics:
    """The scenario's `SimAgentMetrics` from its features (`metric_features.compute_scenario_rollouts_features`).

    Args:
      config: the metrics config.
      scenario_id: stored in the message.
      log_features: `metric_features.MetricFeatures` of the log (n_samples=1).
      sim_features: `metric_features.MetricFeatures` of the rollouts (n_samples=number of rollouts); any
        object with those fields works (numpy arrays, or anything `np.asarray` reads).
    """
    values = scenario_metrics(config, as_internal(log_features), as_internal(sim_features))
    return sim_agents_metrics_pb2.SimAgentMetrics(scenario_id=scenario_id, **values)
