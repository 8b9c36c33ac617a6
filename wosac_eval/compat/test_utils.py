"""`waymo_open_dataset.utils.sim_agents.test_utils`, without TensorFlow: what the official tests (and some
users' tests) build their cases from.

    config = test_utils.load_test_metrics_config()  # the official tests' metrics config
    trajectories = test_utils.get_test_simulated_trajectories(scenario, ChallengeType.SIM_AGENTS, 80)
    submission = test_utils.load_test_submission()

The two test configs lie under the compat root at the official relative path
(`utils/sim_agents/testdata/`). The test submission (32 rollouts of scenario 637f20cafde22ff8) is data of
the official repository under the Waymo Dataset License, which wosac-eval does not redistribute: it is
read where the official function reads it, relative to the working folder
(`waymo_open_dataset/utils/sim_agents/testdata/test_submission.binproto`), or from the same relative path
under the compat root.
"""

from __future__ import annotations

from pathlib import Path

from google.protobuf import text_format

from wosac_eval.compat import submission_specs
from wosac_eval.protos import scenario_pb2, sim_agents_metrics_pb2, sim_agents_submission_pb2

TESTDATA = "utils/sim_agents/testdata"
_ROOT = Path(__file__).resolve().parent  # the official package's root, as wosac_eval.compat lays it out
_SUBMISSION = "test_submission.binproto"


def get_test_simulated_trajectories(
    scenario: scenario_pb2.Scenario, challenge_type: submission_specs.ChallengeType, num_sim_steps: int
) -> list[sim_agents_submission_pb2.SimulatedTrajectory]:
    """One all-zero trajectory of `num_sim_steps` steps per sim agent of the scenario, in track order."""
    config = submission_specs.get_submission_config(challenge_type)
    zeros = [0.0] * num_sim_steps
    return [
        sim_agents_submission_pb2.SimulatedTrajectory(
            center_x=zeros, center_y=zeros, center_z=zeros, heading=zeros, object_id=track.id
        )
        for track in scenario.tracks
        if config.is_valid_sim_agent(track)
    ]


def submission_paths() -> list[Path]:
    """Where `load_test_submission` looks, in order: the official place (relative to the working folder), then
    the same relative path under the compat root."""
    return [Path("waymo_open_dataset", TESTDATA, _SUBMISSION), _ROOT / TESTDATA / _SUBMISSION]


def load_test_submission() -> sim_agents_submission_pb2.SimAgentsChallengeSubmission:
    """The official test submission: 32 constant-velocity rollouts of scenario 637f20cafde22ff8.

    Raises:
      FileNotFoundError: it is in neither place of `submission_paths` (naming both, and where it comes from).
    """
    for path in submission_paths():
        if path.is_file():
            return sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(path.read_bytes())
    places = " or ".join(str(p) for p in submission_paths())
    raise FileNotFoundError(
        f"the official test submission is not at {places}: it is data of the waymo-open-dataset repository "
        f"(src/waymo_open_dataset/{TESTDATA}/{_SUBMISSION}, Waymo Dataset License), which wosac-eval does not "
        "redistribute; put it at one of those paths"
    )


def _config(name: str) -> sim_agents_metrics_pb2.SimAgentMetricsConfig:
    text = (_ROOT / TESTDATA / name).read_text(encoding="utf-8")
    return text_format.Parse(text, sim_agents_metrics_pb2.SimAgentMetricsConfig())


def load_test_metrics_config() -> sim_agents_metrics_pb2.SimAgentMetricsConfig:
    """The official tests' metrics config: histograms over independent timesteps, every weight 1."""
    return _config("test_config.textproto")


def load_identity_function_test_metrics_config() -> sim_agents_metrics_pb2.SimAgentMetricsConfig:
    """The official tests' config under which the log scored against itself gives likelihoods close to 1
    (histograms per step, minimal smoothing)."""
    return _config("test_config_dependent_timesteps.textproto")
