"""The scoring step of an evaluation pool, written for the official waymo-open-dataset package (unchanged): it
imports the official modules at its top, so a worker process that unpickles its function needs them before
anything of the pool's program runs there."""

import os

import waymo_open_dataset
from google.protobuf import text_format
from waymo_open_dataset.protos import scenario_pb2, sim_agents_metrics_pb2, sim_agents_submission_pb2
from waymo_open_dataset.utils.sim_agents import submission_specs
from waymo_open_dataset.wdl_limited.sim_agents_metrics import metrics

CONFIG_PATH = os.path.join(
    waymo_open_dataset.__path__[0], "wdl_limited/sim_agents_metrics/challenge_2025_sim_agents_config.textproto"
)


def score_files(paths: tuple) -> dict:
    """The metrics of one scenario's rollouts: (scenario file, rollouts file) -> what the pool collects."""
    scenario_path, rollouts_path = paths
    with open(CONFIG_PATH) as f:
        config = text_format.Parse(f.read(), sim_agents_metrics_pb2.SimAgentMetricsConfig())
    with open(scenario_path, "rb") as f:
        scenario = scenario_pb2.Scenario.FromString(f.read())
    with open(rollouts_path, "rb") as f:
        rollouts = sim_agents_submission_pb2.ScenarioRollouts.FromString(f.read())
    submission_specs.validate_scenario_rollouts(rollouts, scenario)
    scored = metrics.compute_scenario_metrics_for_bundle(config, scenario, rollouts)
    return {
        "scenario_id": scored.scenario_id,
        "metametric": scored.metametric,
        "pid": os.getpid(),
        "metrics_module": metrics.__name__,
    }


def where_served(_) -> dict:
    """What a worker imported for the official names, without scoring (a quick look at a fresh installation)."""
    return {"config": os.path.isfile(CONFIG_PATH), "metrics_module": metrics.__name__, "pid": os.getpid()}
