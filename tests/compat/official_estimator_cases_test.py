"""The official unit tests' cases of estimators (estimators_test) and of what the official tests build on
`utils/sim_agents/test_utils` (the test configs, zero trajectories, the test submission: metrics_test's cases
that use them), through the compat names only."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from wosac_eval.compat import estimators, metric_features, metrics, submission_specs
from wosac_eval.compat import test_utils as sim_agents_test_utils
from wosac_eval.protos import sim_agents_metrics_pb2

_Config = sim_agents_metrics_pb2.SimAgentMetricsConfig
TEST_HISTOGRAM = _Config.HistogramEstimate(min_val=0.0, max_val=1.0, num_bins=10, additive_smoothing_pseudocount=0.0)
F = np.float32


@pytest.mark.parametrize("pseudocount", [0.0, 0.0001])
def test_histogram_of_one_sample_per_batch_is_certain(pseudocount):
    samples = np.array([[0.05], [0.15], [0.25]], F)
    config = _Config.HistogramEstimate(
        min_val=0.0, max_val=1.0, num_bins=10, additive_smoothing_pseudocount=pseudocount
    )
    np.testing.assert_allclose(np.exp(estimators.histogram_estimate(config, samples, samples)), 1.0, atol=0.001)


@pytest.mark.parametrize("independent", [False, True])
@pytest.mark.parametrize("aggregate", [False, True])
def test_timeseries_estimate_shape(independent, aggregate):
    config = _Config.FeatureConfig(
        histogram=TEST_HISTOGRAM, independent_timesteps=independent, metametric_weight=0.0, aggregate_objects=aggregate
    )
    out = estimators.log_likelihood_estimate_timeseries(
        config, log_values=np.zeros((4, 80)), sim_values=np.zeros((32, 4, 80))
    )
    assert out.shape == (4, 80) and out.dtype == np.float32


@pytest.mark.parametrize("aggregate", [True, False])
def test_scenario_level_estimate_shape(aggregate):
    config = _Config.FeatureConfig(histogram=TEST_HISTOGRAM, metametric_weight=0.0, aggregate_objects=aggregate)
    out = estimators.log_likelihood_estimate_scenario_level(
        config, log_values=np.zeros(4), sim_values=np.zeros((32, 4))
    )
    assert out.shape == (4,)


def _populations() -> np.ndarray:
    """A uniform and a normal population of 10,000 samples each."""
    rng = np.random.default_rng(0)
    return np.stack([rng.uniform(size=10_000), rng.normal(0.5, 0.2, 10_000)]).astype(F)


def test_histogram_follows_the_populations():
    log = np.array([[0.0, 0.15, 0.5, 1.0]] * 2, F)
    out = estimators.histogram_estimate(TEST_HISTOGRAM, log, _populations())
    assert out.shape == (2, 4)
    np.testing.assert_allclose(out[0] - out[0].mean(), 0.0, atol=0.1)  # uniform: every bin alike
    assert np.argmax(out[1]) == 2  # normal around 0.5: its bin is the likeliest


def test_kernel_density_follows_the_populations():
    log = np.array([[0.15, 0.25, 0.5, 0.75], [0.0, 0.15, 0.5, 1.0]], F)
    out = estimators.kernel_density_estimate(_Config.KernelDensityEstimate(bandwidth=0.01), log, _populations())
    assert out.shape == (2, 4)
    np.testing.assert_allclose(out[0] - out[0].mean(), 0.0, atol=0.1)
    assert np.argmax(out[1]) == 2


@pytest.mark.parametrize(
    "estimate",
    [
        lambda: estimators.histogram_estimate(TEST_HISTOGRAM, np.zeros((3, 5)), np.zeros((5, 5))),
        lambda: estimators.kernel_density_estimate(
            _Config.KernelDensityEstimate(bandwidth=1.0), np.zeros((3, 5)), np.zeros((5, 5))
        ),
    ],
    ids=["histogram", "kernel density"],
)
def test_estimates_refuse_different_batch_sizes(estimate):
    with pytest.raises(ValueError, match="Log and Sim batch sizes must be equal."):
        estimate()


def test_kernel_density_refuses_a_bandwidth_of_zero():
    with pytest.raises(ValueError, match="Bandwidth needs to be positive for KernelDensity estimation."):
        estimators.kernel_density_estimate(
            _Config.KernelDensityEstimate(bandwidth=0.0), np.zeros((1, 1)), np.zeros((1, 1))
        )


@pytest.mark.parametrize(("pseudocount", "infinite"), [(None, False), (0.0, True), (1.0, False)])
def test_histogram_adds_the_pseudocount(pseudocount, infinite):
    config = _Config.HistogramEstimate(min_val=0.0, max_val=1.0, num_bins=10)
    if pseudocount is not None:
        config.additive_smoothing_pseudocount = pseudocount
    out = estimators.histogram_estimate(config, np.array([[0.5]], F), np.array([[0.0, 0.0, 0.0, 1.0]], F))
    assert (out[0, 0] == -np.inf) == infinite


def test_bernoulli_values():
    sim = np.array([[False] * 4, [True] * 4, [False] * 4, [True] * 4, [True, False, False, False]])
    log = np.array([[False], [True], [True], [False], [True]])
    out = estimators.bernoulli_estimate(_Config.BernoulliEstimate(), log, sim)
    assert out.shape == (5, 1)
    np.testing.assert_allclose(np.exp(out[:2]), 1.0, atol=1e-2)
    np.testing.assert_allclose(np.exp(out[2:4]), 0.0, atol=1e-2)
    np.testing.assert_allclose(np.exp(out[4:]), 0.25, atol=1e-2)


def test_bernoulli_refuses_numbers():
    with pytest.raises(ValueError, match="Tensor `log_samples` must be a boolean tensor for BernoulliEstimate."):
        estimators.bernoulli_estimate(_Config.BernoulliEstimate(), np.zeros((1, 1)), np.zeros((1, 1), bool))


# --- test_utils and the metrics_test cases built on it ----------------------------------------------


def test_the_test_configs_load_from_anywhere(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config = sim_agents_test_utils.load_test_metrics_config()
    assert config.linear_speed.independent_timesteps and config.linear_speed.metametric_weight == 1.0
    identity = sim_agents_test_utils.load_identity_function_test_metrics_config()
    assert not identity.linear_speed.independent_timesteps
    assert identity.traffic_light_violation.metametric_weight == 0.0


def test_zero_trajectories_for_every_sim_agent(womd_test_scenario):
    for challenge in submission_specs.ChallengeType:
        trajectories = sim_agents_test_utils.get_test_simulated_trajectories(womd_test_scenario, challenge, 80)
        assert [t.object_id for t in trajectories] == submission_specs.get_sim_agent_ids(womd_test_scenario, challenge)
        assert all(list(t.center_x) == [0.0] * 80 and len(t.heading) == 80 for t in trajectories)


def test_the_test_submission_is_read_where_the_official_reads_it(official_testdata, tmp_path, monkeypatch):
    submission = sim_agents_test_utils.load_test_submission()
    assert submission.scenario_rollouts[0].scenario_id == "637f20cafde22ff8"
    assert len(submission.scenario_rollouts[0].joint_scenes) == 32
    monkeypatch.chdir(tmp_path / "waymo_open_dataset")  # elsewhere it is not found, and the message says where
    with pytest.raises(FileNotFoundError, match="does not redistribute"):
        sim_agents_test_utils.load_test_submission()


def test_scenario_metrics_of_the_test_submission(womd_test_scenario, official_testdata):
    config = sim_agents_test_utils.load_test_metrics_config()
    rollouts = sim_agents_test_utils.load_test_submission().scenario_rollouts[0]
    log_features, sim_features = metric_features.compute_scenario_rollouts_features(
        womd_test_scenario, rollouts, submission_specs.ChallengeType.SIM_AGENTS
    )
    scored = metrics.compute_scenario_metrics_for_features_bundle(
        config, womd_test_scenario.scenario_id, log_features, sim_features
    )
    assert scored.HasField("scenario_id")
    assert scored.average_displacement_error > 0 and scored.min_average_displacement_error > 0
    likelihoods = [f.name for f in scored.DESCRIPTOR.fields if f.name.endswith("_likelihood")]
    assert len(likelihoods) == 10 and all(0.0 <= getattr(scored, name) <= 1.0 for name in likelihoods)
    assert scored.metametric > 0.0
    for rate in ("simulated_collision_rate", "simulated_offroad_rate", "simulated_traffic_light_violation_rate"):
        assert 0.0 <= getattr(scored, rate) <= 1.0
    # An object that is not a vehicle keeps its time-to-collision likelihood whatever its values.
    others = np.array([False, False, True, False])[None, :, None]
    changed = dataclasses.replace(sim_features, time_to_collision=np.where(others, 0.0, sim_features.time_to_collision))
    again = metrics.compute_scenario_metrics_for_features_bundle(
        config, womd_test_scenario.scenario_id, log_features, changed
    )
    assert round(again.time_to_collision_likelihood, 2) == round(scored.time_to_collision_likelihood, 2)


def test_buckets_of_the_test_config():
    config = sim_agents_test_utils.load_test_metrics_config()
    config.collision_indication.metametric_weight = 2.0
    values = {
        "metametric": 0.1,
        "average_displacement_error": 0.2,
        "min_average_displacement_error": 0.3,
        "linear_speed_likelihood": 0.5,
        "linear_acceleration_likelihood": 0.5,
        "angular_speed_likelihood": 0.5,
        "angular_acceleration_likelihood": 0.5,
        "distance_to_nearest_object_likelihood": 0.0,
        "collision_indication_likelihood": 1.0,
        "time_to_collision_likelihood": 0.0,
        "distance_to_road_edge_likelihood": 1.0,
        "offroad_indication_likelihood": 1.0,
        "traffic_light_violation_likelihood": 1.0,
        "simulated_collision_rate": 0.5,
        "simulated_offroad_rate": 0.5,
        "simulated_traffic_light_violation_rate": 0.5,
    }
    buckets = metrics.aggregate_metrics_to_buckets(config, sim_agents_metrics_pb2.SimAgentMetrics(**values))
    expected = sim_agents_metrics_pb2.SimAgentsBucketedMetrics(
        realism_meta_metric=0.1,
        min_ade=0.3,
        kinematic_metrics=0.5,
        interactive_metrics=0.5,
        map_based_metrics=1.0,
        simulated_collision_rate=0.5,
        simulated_offroad_rate=0.5,
        simulated_traffic_light_violation_rate=0.5,
    )
    for field in expected.DESCRIPTOR.fields:
        assert getattr(buckets, field.name) == pytest.approx(getattr(expected, field.name), abs=1e-6), field.name
