"""A per-step feature declared from this file alone (`features.registry`), scored with numpy and with JAX.

The toy feature is the planar distance an object moved since the previous step; its metric, `step_length`,
is a histogram time series in the kinematic bucket whose config lives in its registry entry (the official
proto has no field for it) and is scored into `step_length_likelihood`. The official features and
likelihoods are unchanged by it; the meta-metric and the kinematic bucket take its weight.
"""

from __future__ import annotations

import functools
import pickle

import numpy as np
import pytest

from support import golden
from wosac_eval.arrays.samples import sample_batch
from wosac_eval.features import metric_features as mf
from wosac_eval.features import registry
from wosac_eval.metrics import registry as metric_registry
from wosac_eval.metrics.config import load_config
from wosac_eval.metrics.scenario_metrics import SCENARIO_FIELDS, bucket_metrics, scenario_metrics

WEIGHT = 0.1
CASE_SET = golden.SETS[2]  # the oracle cases in the repository


def step_length(context: registry.FeatureContext):
    """Planar distance from the previous step, float32 `(num_samples, num_evaluated, reported steps)`; 0 at
    the first step (numpy or JAX: `context.xp`)."""
    xp = context.xp
    x, y = (context.evaluated(context.traj[f]) for f in ("x", "y"))
    dx, dy = x[..., 1:] - x[..., :-1], y[..., 1:] - y[..., :-1]
    moved = xp.sqrt(dx * dx + dy * dy)
    return context.reported(xp.concatenate([xp.zeros_like(moved[..., :1]), moved], axis=-1))


STEP_LENGTH = registry.Feature(
    name="step_length",
    kernel=step_length,
    metric=metric_registry.Metric(
        name="step_length",
        bucket="kinematic",
        feature="step_length",
        per_object=False,
        mask="speed",
        official=False,
        config_default="histogram { min_val: 0.0 max_val: 4.0 num_bins: 20 additive_smoothing_pseudocount: 0.1 } "
        f"independent_timesteps: true metametric_weight: {WEIGHT}",
    ),
)


@pytest.fixture
def toy_feature():
    with registry.registered(STEP_LENGTH):
        yield STEP_LENGTH
    assert "step_length" not in registry.feature_names()
    assert "step_length_likelihood" not in metric_registry.active_likelihood_fields()


def _case():
    return golden.inputs(CASE_SET, CASE_SET.cases[0])


def _expected_step_length(scenario, rollouts) -> np.ndarray:
    """The toy feature computed here from the batch's trajectories (log sample first)."""
    batch = sample_batch(scenario, rollouts)
    e, reported = batch.num_evaluated, slice(batch.spec.first_simulated_step, None)
    x, y = batch.trajectories.x[:, :e], batch.trajectories.y[:, :e]
    moved = np.sqrt(np.square(np.diff(x, axis=-1)) + np.square(np.diff(y, axis=-1)))
    return np.concatenate([np.zeros_like(moved[..., :1]), moved], axis=-1)[..., reported]


def test_numpy_features_and_metrics(toy_feature):
    scenario, rollouts = _case()
    config = load_config("2025")
    log, sim = mf.scenario_features(scenario, rollouts)
    both = np.concatenate([log.extra["step_length"], sim.extra["step_length"]])
    np.testing.assert_array_equal(both, _expected_step_length(scenario, rollouts))

    with_toy = scenario_metrics(config, log, sim)
    assert 0 < with_toy["step_length_likelihood"] <= 1
    with registry_without(toy_feature):
        official_log, official_sim = mf.scenario_features(scenario, rollouts)
        official = scenario_metrics(config, official_log, official_sim)
    assert official_log.extra == {} and "step_length_likelihood" not in official
    for field in SCENARIO_FIELDS:
        if field != "metametric":
            assert with_toy[field] == official[field], field
    assert with_toy["metametric"] == pytest.approx(
        official["metametric"] + WEIGHT * with_toy["step_length_likelihood"], abs=1e-6
    )
    # The kinematic bucket now weighs four official metrics and the toy one.
    buckets = bucket_metrics(config, with_toy)
    weights = {
        m.name: metric_registry.metric_config(config, m).metametric_weight
        for m in metric_registry.active_metrics()
        if m.bucket == "kinematic"
    }
    kinematic = sum(w * with_toy[f"{m}_likelihood"] for m, w in weights.items()) / sum(weights.values())
    assert buckets["kinematic_metrics"] == pytest.approx(kinematic, abs=1e-6)


def test_every_entry_comes_back_equal_from_a_worker_process():
    """Entries travel to worker processes pickled; the JAX backend finds its compiled programs by their
    equality, so an entry must equal itself after the round trip (a `functools.partial` kernel did not)."""
    for feature in registry.features():
        assert pickle.loads(pickle.dumps(feature)) == feature, feature.name
        assert hash(pickle.loads(pickle.dumps(feature))) == hash(feature), feature.name


class registry_without:
    """The registry without `feature` for a `with` block (registered again on the way out)."""

    def __init__(self, feature):
        self.feature = feature

    def __enter__(self):
        registry.unregister(self.feature.name)

    def __exit__(self, *exc):
        registry.register(self.feature)


def test_registration_is_checked():
    with pytest.raises(ValueError, match="already registered"):
        registry.register(registry.Feature("linear_speed", step_length))
    with pytest.raises(ValueError, match="unknown map parts"):
        registry.register(registry.Feature("toy", step_length, needs=("sidewalks",)))
    with pytest.raises(ValueError, match="lambda or a functools.partial"):
        registry.register(registry.Feature("toy", functools.partial(step_length)))
    with pytest.raises(ValueError, match="lambda or a functools.partial"):
        registry.register(registry.Feature("toy", lambda context: step_length(context)))
    with pytest.raises(ValueError, match="not official"):
        registry.register(
            registry.Feature(
                "toy", step_length, metric=metric_registry.Metric("toy", "kinematic", "toy", False, "valid")
            )
        )
    assert registry.feature_names() == registry.OFFICIAL_FEATURE_NAMES


@pytest.mark.jax
@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_jax_backend_and_realism_equal_numpy(toy_feature):
    import jax

    from wosac_eval import jax_realism
    from wosac_eval.backends import jax_backend

    scenario, rollouts = _case()
    log, sim = mf.scenario_features(scenario, rollouts)
    expected = scenario_metrics(load_config("2025"), log, sim)

    jax_log, jax_sim = jax_backend.scenario_features(scenario, rollouts)
    for ours, theirs in ((jax_log, log), (jax_sim, sim)):
        np.testing.assert_array_equal(ours.extra["step_length"], theirs.extra["step_length"])
        np.testing.assert_array_equal(ours.linear_speed, theirs.linear_speed)

    prepared = jax_realism.prepare([scenario], search="host")
    with jax.enable_x64(True):
        out = jax_realism.realism(prepared, **jax_realism.stack_rollouts(prepared, [rollouts]), mode="exact")
    for field in ("step_length_likelihood", "metametric", "linear_speed_likelihood"):
        # The exact mode's value is numpy's, bit for bit (as float32, as results store it).
        assert np.float32(np.asarray(out[field])[0]) == np.float32(expected[field]), field
