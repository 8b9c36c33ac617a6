"""Write the official arithmetic's answers on small inputs: tests/data/oracle_arithmetic/cases.npz.

    ~/.wosac-oracle/bin/python scripts/oracle_arithmetic_cases.py [OUT.npz]

Runs in the oracle venv (TensorFlow 2.13 and waymo-open-dataset 1.6.7; never imported by the
project or its CI). For each kind of operation the official metrics apply after the features, it
records inputs and what the official code returns for them, so that the tests check the
project's float32 arithmetic against the official kernels bit for bit without TensorFlow:

- `log/<n>`, `exp/<n>`: `tf.math.log` / `tf.exp` of float32 tensors of n values (packets and the
  C library's tail), and `logf/scalars`, `expf/scalars`: one-value tensors (the C library alone);
- `sum/<n>`, `mean/<n>`: `tf.reduce_sum` / `tf.reduce_mean` of n values, and `rowsum/<n>`,
  `rowmean/<n>` of a (3, n) tensor along its last axis;
- `histogram/<k>`, `bernoulli/<k>`: the official `histogram_estimate` / `bernoulli_estimate`;
- `timeseries/<k>`: `log_likelihood_estimate_timeseries` under agent- and scene-level configs;
- `masked_mean/<k>`: the metrics' average of log-likelihoods over valid entries, then `tf.exp`.

The inputs are drawn from a fixed seed and stored beside the answers.
"""

import os
import sys

os.environ["TF_CPP_MIN_LOG_LEVEL"] = "3"

import numpy as np  # noqa: E402
import tensorflow as tf  # noqa: E402
from waymo_open_dataset.protos import sim_agents_metrics_pb2  # noqa: E402
from waymo_open_dataset.wdl_limited.sim_agents_metrics import estimators  # noqa: E402

F = np.float32
Config = sim_agents_metrics_pb2.SimAgentMetricsConfig
SPECIAL = np.array([0.0, 1.0, np.inf, -np.inf, np.nan, -1.0, 1e-40, 3e-39, 1e-45], F)


def elementwise(out, rng):
    for n in (1, 2, 7, 8, 9, 16, 17, 40, 41, 100, 333):
        counts = (rng.integers(0, 3000, n) + rng.choice([0.001, 0.1, 1.0], n)).astype(F)
        spread = rng.uniform(-20, 20, n).astype(F)
        x = np.where(rng.random(n) < 0.5, counts, np.exp2(spread).astype(F))
        out[f"log/{n}/in"], out[f"log/{n}/out"] = x, tf.math.log(x).numpy()
        y = rng.uniform(-110, 90, n).astype(F)
        out[f"exp/{n}/in"], out[f"exp/{n}/out"] = y, tf.exp(y).numpy()
    x = np.concatenate([rng.uniform(0, 3000, 3000), np.exp2(rng.uniform(-140, 120, 1000)), SPECIAL]).astype(F)
    out["logf/scalars/in"] = x
    out["logf/scalars/out"] = np.array([tf.math.log(v).numpy() for v in x], F)
    y = np.concatenate([rng.uniform(-105, 89, 3000), rng.uniform(-1, 1, 1000), SPECIAL]).astype(F)
    out["expf/scalars/in"] = y
    out["expf/scalars/out"] = np.array([tf.exp(v).numpy() for v in y], F)


def sums(out, rng):
    for n in (1, 5, 8, 31, 32, 33, 100, 321, 1000, 4000, 8192, 8193, 16385):
        x = rng.normal(0, 3, n).astype(F)
        out[f"sum/{n}/in"], out[f"sum/{n}/out"] = x, tf.reduce_sum(x).numpy()
        out[f"mean/{n}/out"] = tf.reduce_mean(x).numpy()
        if n <= 8192:
            rows = rng.normal(0, 3, (3, n)).astype(F)
            out[f"rowsum/{n}/in"] = rows
            out[f"rowsum/{n}/out"] = tf.reduce_sum(rows, axis=1).numpy()
            out[f"rowmean/{n}/out"] = tf.reduce_mean(rows, axis=1).numpy()


def _histogram_config(rng):
    low, high = sorted(rng.uniform(-5, 30, 2))
    return Config.HistogramEstimate(
        min_val=low,
        max_val=high,
        num_bins=int(rng.choice([2, 10, 20, 21, 50, 100])),
        additive_smoothing_pseudocount=float(rng.choice([0.0, 0.001, 0.1, 1.0])),
    )


def estimates(out, rng):
    for k in range(40):
        h = _histogram_config(rng)
        batch, n_sim, n_log = int(rng.integers(1, 30)), int(rng.choice([1, 32, 80, 400])), int(rng.choice([1, 80]))
        sim = rng.uniform(h.min_val - 1, h.max_val + 1, (batch, n_sim)).astype(F)
        log = rng.uniform(h.min_val - 1, h.max_val + 1, (batch, n_log)).astype(F)
        sim[rng.random(sim.shape) < 0.01] = np.nan
        out[f"histogram/{k}/config"] = np.array([h.min_val, h.max_val, h.num_bins, h.additive_smoothing_pseudocount])
        out[f"histogram/{k}/log"], out[f"histogram/{k}/sim"] = log, sim
        out[f"histogram/{k}/out"] = estimators.histogram_estimate(h, tf.constant(log), tf.constant(sim)).numpy()
    for k in range(12):
        pseudocount = float(rng.choice([0.001, 1.0]))
        batch, n_sim = int(rng.integers(1, 40)), int(rng.choice([1, 32]))
        sim = rng.random((batch, n_sim)) < rng.choice([0.0, 0.05, 0.5, 1.0])
        log = rng.random((batch, 1)) < 0.3
        out[f"bernoulli/{k}/pseudocount"] = np.array(pseudocount)
        out[f"bernoulli/{k}/log"], out[f"bernoulli/{k}/sim"] = log, sim
        b = Config.BernoulliEstimate(additive_smoothing_pseudocount=pseudocount)
        out[f"bernoulli/{k}/out"] = estimators.bernoulli_estimate(b, tf.constant(log), tf.constant(sim)).numpy()


def timeseries(out, rng):
    k = 0
    for aggregate in (False, True):
        for independent in (True, False):
            for n_objects in (1, 3, 9, 12):
                config = Config.FeatureConfig(independent_timesteps=independent, aggregate_objects=aggregate)
                config.histogram.CopyFrom(_histogram_config(rng))
                n_steps = int(rng.choice([80, 91]))
                sim = rng.uniform(config.histogram.min_val, config.histogram.max_val, (8, n_objects, n_steps))
                log = rng.uniform(config.histogram.min_val, config.histogram.max_val, (n_objects, n_steps))
                out[f"timeseries/{k}/config"] = np.frombuffer(config.SerializeToString(), np.uint8)
                out[f"timeseries/{k}/log"], out[f"timeseries/{k}/sim"] = log.astype(F), sim.astype(F)
                out[f"timeseries/{k}/out"] = estimators.log_likelihood_estimate_timeseries(
                    config, tf.constant(log.astype(F)), tf.constant(sim.astype(F))
                ).numpy()
                k += 1


def masked_means(out, rng):
    for k, (n_objects, n_steps) in enumerate(((1, 80), (3, 80), (9, 80), (50, 91), (91, 91), (120, 91))):
        values = rng.uniform(-12, 0, (n_objects, n_steps)).astype(F)
        valid = rng.random((n_objects, n_steps)) < 0.9
        out[f"masked_mean/{k}/values"], out[f"masked_mean/{k}/valid"] = values, valid
        # What the official metrics do with a feature's log-likelihoods: the sum over the valid entries
        # (`tf.where` then `tf.reduce_sum`), divided by their count, then `tf.exp`.
        total = tf.reduce_sum(tf.where(tf.constant(valid), tf.constant(values), tf.zeros_like(values)))
        out[f"masked_mean/{k}/out"] = tf.exp(total / tf.reduce_sum(tf.cast(valid, tf.float32))).numpy()


def main() -> None:
    target = sys.argv[1] if len(sys.argv) > 1 else "tests/data/oracle_arithmetic/cases.npz"
    rng = np.random.default_rng(20261207)
    out: dict = {}
    for part in (elementwise, sums, estimates, timeseries, masked_means):
        part(out, rng)
    os.makedirs(os.path.dirname(target) or ".", exist_ok=True)
    np.savez_compressed(target, **out)
    print(f"{target}: {len(out)} arrays")


if __name__ == "__main__":
    main()
