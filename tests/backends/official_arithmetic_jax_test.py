"""The official arithmetic after the features under `jax.jit`, padded, in the exact mode: the official bits.

The same cases as the numpy tests (`tests/data/oracle_arithmetic`), each set behind padding whose real
size is a traced count (the JAX backends' layout): the sums and means (the tree of halves included),
`log` and `exp` of tensors, and the estimators of scenario-level and agent-level configs. One jitted
program per test, so that few programs are compiled.
"""

from __future__ import annotations

import numpy as np
import pytest

import jax
import jax.numpy as jnp

from support import oracle_arithmetic as oracle
from wosac_eval.backends.exact_rounding import exactly_rounded
from wosac_eval.estimators import likelihoods
from wosac_eval.features.float32_explog import tensor_exp32, tensor_log32
from wosac_eval.features.float32_sums import eigen_mean32, eigen_sum32
from wosac_eval.protos import sim_agents_metrics_pb2

F = np.float32
PAD = 37  # padding values past each official tensor


def exact(fn, *args):
    """`fn(*args)` jitted in the exact mode (x64 while tracing, the rounding rewrite), back as numpy."""
    with jax.enable_x64(True):
        rewritten = jax.jit(exactly_rounded(fn))
        return jax.tree_util.tree_map(np.asarray, rewritten(jnp.zeros((), jnp.int64), *args))


def padded(values, fill=F(3.5)):
    return np.concatenate([values, np.full(PAD, fill, F)])


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_sums_and_means_behind_padding():
    keys = ["1", "33", "321", "8192", "8193", "16385"]
    inputs = [(padded(oracle.case("sum", k)["in"]), np.int32(int(k))) for k in keys]
    got = exact(lambda pairs: [(eigen_sum32(v, n), eigen_mean32(v, n)) for v, n in pairs], inputs)
    for key, (total, mean) in zip(keys, got):
        oracle.assert_bits_equal(total, oracle.case("sum", key)["out"], f"sum of {key}")
        oracle.assert_bits_equal(mean, oracle.case("mean", key)["out"], f"mean of {key}")


def test_log_and_exp_of_tensors_behind_padding():
    keys = ["1", "7", "9", "41", "333"]
    logs = [(padded(oracle.case("log", k)["in"]), np.int32(int(k))) for k in keys]
    exps = [(padded(oracle.case("exp", k)["in"]), np.int32(int(k))) for k in keys]
    got = exact(lambda a, b: ([tensor_log32(v, n) for v, n in a], [tensor_exp32(v, n) for v, n in b]), logs, exps)
    for key, log, exp in zip(keys, *got):
        n = int(key)
        oracle.assert_bits_equal(log[:n], oracle.case("log", key)["out"], f"log of {key}")
        oracle.assert_bits_equal(exp[:n], oracle.case("exp", key)["out"], f"exp of {key}")


# One timeseries case of each layout: agent- and scene-level, independent and dependent timesteps.
LAYOUTS = ("2", "6", "10", "14")


@pytest.mark.slow  # one program of four estimators behind padding: about 9 s to compile on 2 cores
def test_estimators_behind_padding_objects():
    """A timeseries case of each layout, three padding objects each (the object mask names the real ones)."""
    configs, inputs, wants = [], [], []
    for key in LAYOUTS:
        c = oracle.case("timeseries", key)
        configs.append(sim_agents_metrics_pb2.SimAgentMetricsConfig.FeatureConfig.FromString(c["config"].tobytes()))
        n_rollouts, n_objects, n_steps = c["sim"].shape
        log = np.concatenate([c["log"], np.full((3, n_steps), 0.5, F)])
        sim = np.concatenate([c["sim"], np.full((n_rollouts, 3, n_steps), 0.5, F)], axis=1)
        inputs.append((log, sim, np.arange(n_objects + 3) < n_objects))
        wants.append(c["out"])

    def scored(batch):
        return [
            likelihoods.timeseries_log_likelihood(cfg, *args[:2], object_mask=args[2])
            for cfg, args in zip(configs, batch)
        ]

    for key, got, want in zip(LAYOUTS, exact(scored, inputs), wants):
        oracle.assert_bits_equal(got[: want.shape[0]], want, f"timeseries {key}")
