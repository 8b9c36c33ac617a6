"""`wosac_eval.jax_realism`: realism on device arrays equals the file path, under jit and vmap, padding or not.

On CPU the per-step features are bit-identical to the numpy path (hence to the
official ones), and every metric agrees with `score_scenario` within float32
summation order (the means run as XLA reductions).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from wosac_eval import jax_realism  # first: restricts XLA's CPU code generation before JAX starts

import jax  # noqa: E402

from support import golden  # noqa: E402
from wosac_eval.arrays.scenario import scenario_arrays  # noqa: E402
from wosac_eval.features.metric_features import PER_STEP_FIELDS, scenario_features  # noqa: E402
from wosac_eval.metrics.scenario_metrics import SCENARIO_FIELDS  # noqa: E402
from wosac_eval.scoring.scenario import score_scenario  # noqa: E402
from wosac_eval.sim import scenes  # noqa: E402
from wosac_eval.sim.baselines import policy_rollouts  # noqa: E402

METRIC_TOLERANCE = 1e-5  # the official outputs' tolerance; measured here: below 1e-6


@lru_cache(maxsize=None)
def scene_set(challenge: str):
    """Three demo scenes of different sizes, their rollouts (IDM / scenario-gen log replay) and arrays."""
    scs = [scenes.generate_scenes(10, seed=0)[k] for k in (1, 5, 8)]
    policy = "idm" if challenge == "sim_agents" else "log_replay_noise"
    rollouts = [policy_rollouts(sc, policy, challenge=challenge) for sc in scs]
    return scs, rollouts


@lru_cache(maxsize=None)
def prepared_set(challenge: str, padded: bool = False):
    scs, rollouts = scene_set(challenge)
    prepared = jax_realism.prepare(scs, challenge=challenge, min_sizes=(64, 40, 5000, 8, 700) if padded else None)
    return prepared, jax_realism.stack_rollouts(prepared, rollouts)


def as_numpy(tree):
    return jax.tree_util.tree_map(np.asarray, tree)


@pytest.mark.parametrize("challenge", ["sim_agents", "scenario_gen"])
def test_realism_equals_the_file_path(challenge):
    scs, rollouts = scene_set(challenge)
    prepared, arrays = prepared_set(challenge)
    got = as_numpy(jax_realism.realism(prepared, **arrays))
    for s, (sc, ro) in enumerate(zip(scs, rollouts)):
        expected = score_scenario(sc, ro, challenge=challenge)
        for field in SCENARIO_FIELDS:
            assert got[field].shape == (3,)
            assert abs(float(np.float32(got[field][s])) - expected[field]) <= METRIC_TOLERANCE, (sc.scenario_id, field)


@pytest.mark.parametrize("challenge", ["sim_agents", "scenario_gen"])
def test_features_are_bit_identical_to_numpy(challenge):
    scs, rollouts = scene_set(challenge)
    prepared, arrays = prepared_set(challenge)
    feats = jax_realism.features(prepared, **arrays)
    for s, (sc, ro) in enumerate(zip(scs, rollouts)):
        log, sim = scenario_features(scenario_arrays(sc), ro, challenge=challenge)
        e = log.object_id.size
        for name in PER_STEP_FIELDS + ("average_displacement_error",):
            ours = np.asarray(getattr(feats, name))[s]
            np.testing.assert_array_equal(ours[:1, :e], getattr(log, name), err_msg=f"{sc.scenario_id} log {name}")
            np.testing.assert_array_equal(ours[1:, :e], getattr(sim, name), err_msg=f"{sc.scenario_id} sim {name}")
        np.testing.assert_array_equal(np.asarray(feats.valid)[s][1:, :e], sim.valid)


@pytest.mark.parametrize("challenge", ["sim_agents", "scenario_gen"])
def test_padding_never_changes_a_result(challenge):
    tight, arrays = prepared_set(challenge)
    wide, wide_arrays = prepared_set(challenge, padded=True)
    assert wide.layout.num_evaluated > tight.layout.num_evaluated
    a = as_numpy(jax_realism.realism(tight, **arrays))
    b = as_numpy(jax_realism.realism(wide, **wide_arrays))
    for field in SCENARIO_FIELDS:
        np.testing.assert_allclose(a[field], b[field], rtol=0, atol=1e-6, err_msg=field)
    # Values in the padding columns are ignored.
    noisy = {k: v.copy() for k, v in arrays.items()}
    pad = tight.sim_agent_ids < 0
    for v in noisy.values():
        v[np.broadcast_to(pad[:, None, :, None], v.shape)] = 1e6
    c = as_numpy(jax_realism.realism(tight, **noisy))
    for field in SCENARIO_FIELDS:
        np.testing.assert_array_equal(a[field], c[field], err_msg=field)


def test_jit_and_vmap_inside_a_training_step():
    """Inside the caller's own jit, x64 must be on while it traces (the official arithmetic rounds via float64)."""
    prepared, arrays = prepared_set("sim_agents")

    @jax.jit
    def loss(prepared, shift):
        moved = dict(arrays, x=arrays["x"] + shift)
        return 1.0 - jax_realism.realism(prepared, **moved)["metametric"].mean()

    with jax.enable_x64(True):
        base = float(loss(prepared, 0.0))
        moved = float(loss(prepared, 3.0))
        # vmap over two rollout sets of the same scenes.
        both = {k: np.stack([v, v]) for k, v in arrays.items()}
        batched = jax.vmap(lambda a: jax_realism.realism(prepared, **a))(both)
    expected = 1.0 - np.mean(as_numpy(jax_realism.realism(prepared, **arrays))["metametric"])
    assert base == pytest.approx(expected, abs=1e-9)
    assert moved > base  # rollouts moved 3 m off are less realistic
    np.testing.assert_allclose(np.asarray(batched["metametric"])[1],
                               as_numpy(jax_realism.realism(prepared, **arrays))["metametric"], atol=1e-7)


def test_waymax_style_arrays_in():
    """Objects x timesteps including the history, in Waymax's object order (reversed here), with padding."""
    prepared, arrays = prepared_set("sim_agents")
    scs, _ = scene_set("sim_agents")
    ids = prepared.sim_agent_ids
    n_obj = ids.shape[1] + 2
    object_ids = np.full((3, n_obj), 99999, np.int64)
    waymax = {k: np.zeros((3, 32, n_obj, 91), np.float32) for k in ("x", "y", "z", "yaw")}
    for s in range(3):
        real = ids[s][ids[s] >= 0]
        object_ids[s, : real.size] = real[::-1]
        for a, oid in enumerate(ids[s]):
            if oid < 0:
                continue
            col = int(np.flatnonzero(object_ids[s] == oid)[0])
            for wk, k in (("x", "x"), ("y", "y"), ("z", "z"), ("yaw", "heading")):
                waymax[wk][s, :, col, 11:] = arrays[k][s, :, a]
    columns = jax_realism.waymax_columns(prepared, object_ids)
    picked = jax_realism.from_waymax(prepared, columns, **waymax)
    got = as_numpy(jax_realism.realism(prepared, **picked))
    want = as_numpy(jax_realism.realism(prepared, **arrays))
    for field in SCENARIO_FIELDS:
        np.testing.assert_array_equal(got[field], want[field], err_msg=field)
    with pytest.raises(ValueError, match="not among the Waymax objects"):
        jax_realism.waymax_columns(prepared, np.zeros((3, 4), np.int64))


def test_bad_arrays_are_refused_with_the_shapes():
    prepared, arrays = prepared_set("sim_agents")
    with pytest.raises(ValueError, match=r"x must be \(num_scenes, num_rollouts, max_agents, num_steps\)"):
        jax_realism.realism(prepared, **dict(arrays, x=arrays["x"][..., :79]))
    with pytest.raises(ValueError, match="box sizes from the log"):
        jax_realism.realism(prepared, **arrays, length=arrays["x"])
    sg, sg_arrays = prepared_set("scenario_gen")
    with pytest.raises(ValueError, match="height missing"):
        jax_realism.realism(sg, **{k: v for k, v in sg_arrays.items() if k != "height"})


@pytest.mark.parametrize("case_set", [s for s in golden.SETS], ids=lambda s: s.name)
def test_every_golden_case_matches_the_official_metrics(case_set):
    """All cases of a golden set (real WOMD scenes with ../shared; synthetic oracle cases always) in one batch."""
    cases = case_set.cases
    if not cases:
        golden.skip_if_absent(case_set, None)
    pairs = [golden.inputs(case_set, case) for case in cases]
    config_name = case_set.configs[0]
    config = golden.SHARED_CONFIGS.get(config_name, config_name) if case_set.name == "shared" else config_name
    config = str(golden.SHARED / config) if config.endswith(".textproto") else config
    prepared = jax_realism.prepare([scene for scene, _ in pairs], challenge=case_set.challenge, config=config)
    got = as_numpy(jax_realism.realism(prepared, **jax_realism.stack_rollouts(prepared, [ro for _, ro in pairs])))
    for s, case in enumerate(cases):
        expected = golden.expected_metrics(case_set, case, config_name)
        for field in SCENARIO_FIELDS:
            if field in expected:
                assert abs(float(np.float32(got[field][s])) - expected[field]) <= METRIC_TOLERANCE, (case, field)
