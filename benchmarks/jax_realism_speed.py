"""Realism in the training loop (`wosac_eval.jax_realism`) against the file path, scenes per second.

Ways to score the same scenes and rollouts, each given one warm-up
(compilation for JAX) and the same `--repeat` timed runs:

- in the loop: `prepare` once (timed separately), then `realism(prepared, x, y, z, heading)` inside
  the caller's `jax.jit` on new rollouts every call (moved a little each time, as a training step
  would), in float32 mode (x64 off, JAX's defaults, no XLA flag: as a training loop runs) and in
  exact mode (traced with x64 on);
- the file path with the jax backend, `score_submission(..., backend="jax")` of the same rollouts as
  a submission (parsing, validation, host preparation, device, metrics), in a fresh process that
  opts in to `exact_cpu()` as the CLI does;
- the file path with numpy, one worker and `--workers` workers, in a fresh process without JAX (a
  process that has started JAX must spawn its workers, which would be counted).

Prints scenes per second for each, the projection for the 44,097-scene validation set, the device
in use (`jax.devices()`, a GPU when JAX has one) and, where the device reports it, the peak device
memory per scene of the in-loop call. Pure JAX: nothing here is specific to a CPU.

Usage: python benchmarks/jax_realism_speed.py [--scenes 16] [--repeat 3] [--workers 2]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from bench_env import VALIDATION_SET, median_seconds

import jax
import numpy as np

from wosac_eval import jax_realism
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import make_submission, policy_rollouts



_FILE_PATH_CHILD = """
import statistics, sys, time
from wosac_eval.scoring.submission import score_submission
shards, submission, workers, repeat, backend = sys.argv[1].split(","), sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
if backend == "jax":
    from wosac_eval.backends.jax_backend import exact_cpu
    exact_cpu()
run = lambda: score_submission(shards, submission, analysis=False, workers=workers, backend=backend)
run()
times = []
for _ in range(repeat):
    start = time.perf_counter(); run(); times.append(time.perf_counter() - start)
print(statistics.median(times))
"""


def _file_path(shards, submission, workers: int, repeat: int, backend: str) -> float:
    """Median seconds of `score_submission` in a fresh process (its own JAX or none)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", _FILE_PATH_CHILD, ",".join(map(str, shards)), str(submission),
                           str(workers), str(repeat), backend], capture_output=True, text=True, check=True)
    return float(done.stdout.split()[-1])


def _peak_device_bytes() -> int | None:
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    scenarios = scenes.generate_scenes(args.scenes, seed=7)
    print(f"device: {jax.devices()[0]}; {args.scenes} synthetic scenes, IDM rollouts, sim agents")

    start = time.perf_counter()
    prepared = jax_realism.prepare(scenarios)
    prepare_s = time.perf_counter() - start
    arrays = jax_realism.stack_rollouts(prepared, [policy_rollouts(sc, "idm") for sc in scenarios])
    shift = {"k": 0}

    step = jax.jit(lambda a: jax_realism.realism(prepared, **a))

    def in_loop():
        shift["k"] += 1  # new rollouts every step
        moved = dict(arrays, x=arrays["x"] + np.float32(0.01 * shift["k"]))
        jax.block_until_ready(step(moved))

    float32_s = median_seconds(in_loop, args.repeat, warmup=1)
    peak = _peak_device_bytes()
    with jax.enable_x64(True):
        exact_s = median_seconds(in_loop, args.repeat, warmup=1)
    with tempfile.TemporaryDirectory() as tmp:
        shards = scenes.write_scenario_shards(scenarios, Path(tmp) / "scenarios")
        submission = make_submission(shards, "idm", Path(tmp) / "idm.tar.gz")
        jax_file_s = _file_path(shards, submission, 1, args.repeat, "jax")
        numpy_1_s, numpy_n_s = (_file_path(shards, submission, w, args.repeat, "numpy") for w in (1, args.workers))
    n = args.scenes
    print(f"prepare (once per scene set): {prepare_s:.2f} s ({prepare_s / n * 1e3:.0f} ms/scene)")
    if peak is not None:
        print(f"peak device memory of the float32 in-loop call: {peak / 2**20:.0f} MiB "
              f"({peak / n / 2**20:.1f} MiB per scene)")
    print(f"{'path':44s} {'s/call':>8s} {'scenes/s':>9s} {'44,097 scenes':>14s}")
    for label, seconds in (("in the loop, float32 mode (x64 off)", float32_s),
                           ("in the loop, exact mode (x64 on)", exact_s),
                           ("file path, --backend jax (exact)", jax_file_s),
                           ("file path, numpy, 1 worker", numpy_1_s),
                           (f"file path, numpy, {args.workers} workers", numpy_n_s)):
        print(f"{label:44s} {seconds:8.2f} {n / seconds:9.1f} {VALIDATION_SET * seconds / n / 60:11.1f} min")


if __name__ == "__main__":
    main()
