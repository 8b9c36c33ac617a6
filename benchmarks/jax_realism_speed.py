"""Realism in the training loop (`wosac_eval.jax_realism`) against the file path, scenes per second.

Three ways to score the same scenes and rollouts, in one process, each given
one warm-up (compilation for JAX) and the same `--repeat` timed runs:

- in the loop: `prepare` once (timed separately), then `realism(prepared, x, y, z, heading)` on new
  rollouts every call (the rollouts are moved a little each time, as a training step would);
- the file path with the jax backend: `score_submission(..., backend="jax")` of the same
  rollouts as a submission (parsing, validation, host preparation, device, metrics);
- the file path with numpy, one worker and `--workers` workers, in a fresh process without JAX (a
  process that has started JAX must spawn its workers, which would be counted).

Prints scenes per second for each, and the device in use (`jax.devices()`). On a machine with a
GPU, JAX uses it; this project's development machine has none.

Usage: python benchmarks/jax_realism_speed.py [--scenes 16] [--repeat 3] [--workers 2]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from bench_env import median_seconds

from wosac_eval import jax_realism  # first: XLA flags before JAX starts

import jax  # noqa: E402
import numpy as np  # noqa: E402

from wosac_eval.scoring.submission import score_submission  # noqa: E402
from wosac_eval.sim import scenes  # noqa: E402
from wosac_eval.sim.baselines import make_submission, policy_rollouts  # noqa: E402


_NUMPY_CHILD = """
import statistics, sys, time
from wosac_eval.scoring.submission import score_submission
shards, submission, workers, repeat = sys.argv[1].split(","), sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
run = lambda: score_submission(shards, submission, analysis=False, workers=workers)
run()
times = []
for _ in range(repeat):
    start = time.perf_counter(); run(); times.append(time.perf_counter() - start)
print(statistics.median(times))
"""


def _numpy_file_path(shards, submission, workers: int, repeat: int) -> float:
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", _NUMPY_CHILD, ",".join(map(str, shards)), str(submission),
                           str(workers), str(repeat)], capture_output=True, text=True, check=True)
    return float(done.stdout.split()[-1])


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

    def in_loop():
        shift["k"] += 1  # new rollouts every step
        moved = dict(arrays, x=arrays["x"] + np.float32(0.01 * shift["k"]))
        jax.block_until_ready(jax_realism.realism(prepared, **moved))

    loop_s = median_seconds(in_loop, args.repeat, warmup=1)
    with tempfile.TemporaryDirectory() as tmp:
        shards = scenes.write_scenario_shards(scenarios, Path(tmp) / "scenarios")
        submission = make_submission(shards, "idm", Path(tmp) / "idm.tar.gz")
        jax_file_s = median_seconds(lambda: score_submission(shards, submission, backend="jax", analysis=False),
                                    args.repeat, warmup=1)
        numpy_1_s, numpy_n_s = (_numpy_file_path(shards, submission, w, args.repeat) for w in (1, args.workers))
    n = args.scenes
    print(f"prepare (once per scene set): {prepare_s:.2f} s ({prepare_s / n * 1e3:.0f} ms/scene)")
    for label, seconds in (("in the loop: realism(prepared, rollouts)", loop_s),
                           ("file path, --backend jax", jax_file_s),
                           ("file path, numpy, 1 worker", numpy_1_s),
                           (f"file path, numpy, {args.workers} workers", numpy_n_s)):
        print(f"{label:42s} {seconds:8.2f} s  {n / seconds:8.1f} scenes/s")


if __name__ == "__main__":
    main()
