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

`--search host,device` times the in-loop call with each of `prepare`'s searches (default: "auto",
the host's pruned search on a CPU, the device's fixed-shape one on an accelerator).

`--batch 1,64` also times the in-loop call on the scene set repeated 64 times (prepared once, copied
on the device): a GPU needs batches of hundreds of scenes to be busy. `--womd` takes the real WOMD
scenes of the reference material (`../shared/womd`, or WOSAC_SHARED) instead of synthetic ones.

Usage: python benchmarks/jax_realism_speed.py [--scenes 16] [--repeat 3] [--workers 2] [--batch 1] [--womd]
                                              [--search auto|host|device|host,device]
"""
from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

from bench_env import SHARED, VALIDATION_SET, median_seconds

import jax
import jax.numpy as jnp
import numpy as np

from wosac_eval import jax_realism
from wosac_eval.parse.scenarios import iter_scenarios
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


def repeated(prepared: jax_realism.PreparedScenes, copies: int) -> jax_realism.PreparedScenes:
    """The scene set `copies` times over (copy-major), its device arrays concatenated: a bigger batch
    without preparing the same scenes again."""
    if copies == 1:
        return prepared
    n = prepared.num_scenes
    arrays = tuple(jax.tree_util.tree_map(lambda a: jnp.concatenate([a] * copies), group) for group in prepared.arrays)
    groups = tuple((tuple(c * n + i for c in range(copies) for i in indices), layout)
                   for indices, layout in prepared.groups)
    return dataclasses.replace(prepared, arrays=arrays, groups=groups, scenario_ids=prepared.scenario_ids * copies,
                               agent_ids=prepared.agent_ids * copies)


def in_loop_seconds(prepared, arrays: dict, repeat: int) -> tuple[float, float]:
    """Median seconds of the jitted realism call on new rollouts each time: (float32 mode, exact mode)."""
    shift = {"k": 0}
    step = jax.jit(lambda a: jax_realism.realism(prepared, **a))

    def in_loop():
        shift["k"] += 1  # new rollouts every step
        moved = dict(arrays, x=arrays["x"] + np.float32(0.01 * shift["k"]))
        jax.block_until_ready(step(moved))

    def first_then_median(label: str) -> float:
        start = time.perf_counter()
        in_loop()  # compiles
        print(f"  {prepared.num_scenes} scenes, {label}: first call (compiles) {time.perf_counter() - start:.1f} s",
              flush=True)
        return median_seconds(in_loop, repeat)

    float32_s = first_then_median("float32 mode")
    with jax.enable_x64(True):
        exact_s = first_then_median("exact mode")
    return float32_s, exact_s


def womd_scenarios() -> tuple[list, list]:
    """The real WOMD scenes of the reference material, and the tfrecord files that hold them."""
    files = sorted((SHARED / "womd").glob("*.tfrecord"))
    if not files:
        raise SystemExit(f"--womd needs the WOMD scenarios in {SHARED / 'womd'} (../shared, or WOSAC_SHARED)")
    found = {}
    for f in files:
        for sourced in iter_scenarios(f):
            found.setdefault(sourced.scenario.scenario_id, (sourced.scenario, f))
    return [sc for sc, _ in found.values()], sorted({f for _, f in found.values()})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--batch", default="1", help="comma-separated copies of the scene set for the in-loop call")
    parser.add_argument("--womd", action="store_true", help="the real WOMD scenes of ../shared/womd")
    parser.add_argument("--search", default="auto", help="comma-separated searches of `prepare` to time in the loop")
    args = parser.parse_args()
    copies = [int(c) for c in args.batch.split(",")]
    if args.womd:
        scenarios, shards = womd_scenarios()
        what = f"{len(scenarios)} real WOMD scenes"
    else:
        scenarios, shards = scenes.generate_scenes(args.scenes, seed=7), None
        what = f"{len(scenarios)} synthetic scenes"
    print(f"device: {jax.devices()[0]}; {what}, IDM rollouts (32 each), sim agents")

    def row(label: str, seconds: float, scenes_per_call: int) -> None:  # printed as measured
        print(f"{label:62s} {seconds:8.3f} {scenes_per_call / seconds:9.1f} "
              f"{VALIDATION_SET * seconds / scenes_per_call / 60:11.1f} min", flush=True)

    rollouts = [policy_rollouts(sc, "idm") for sc in scenarios]
    n = len(scenarios)
    for search in args.search.split(","):
        start = time.perf_counter()
        prepared = jax_realism.prepare(scenarios, search=search)
        prepare_s = time.perf_counter() - start
        arrays = jax_realism.stack_rollouts(prepared, rollouts)
        print(f"prepare (once per scene set), {prepared.search} search: {prepare_s:.2f} s "
              f"({prepare_s / n * 1e3:.0f} ms/scene)", flush=True)
        print(f"{'path':62s} {'s/call':>8s} {'scenes/s':>9s} {'44,097 scenes':>14s}", flush=True)
        for c in copies:
            try:
                batch = {k: np.concatenate([v] * c) for k, v in arrays.items()}
                float32_s, exact_s = in_loop_seconds(repeated(prepared, c), batch, args.repeat)
            except Exception as error:  # a batch too big for the device: say so, go on with the others
                print(f"batch of {c * n} scenes: {type(error).__name__}: {str(error).splitlines()[0][:200]}")
                continue
            row(f"in the loop, {prepared.search} search, float32 mode (x64 off), {c * n} scenes", float32_s, c * n)
            row(f"in the loop, {prepared.search} search, exact mode (x64 on), {c * n} scenes", exact_s, c * n)
            peak = _peak_device_bytes()
            if peak is not None:
                print(f"  peak device memory so far: {peak / 2**20:.0f} MiB ({peak / (c * n) / 2**20:.1f} MiB per "
                      f"scene of this batch)", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        if shards is None:
            shards = scenes.write_scenario_shards(scenarios, Path(tmp) / "scenarios")
        submission = make_submission(shards, "idm", Path(tmp) / "idm.tar.gz")
        row("file path, --backend jax (exact)", _file_path(shards, submission, 1, args.repeat, "jax"), n)
        for w in (1, args.workers):
            row(f"file path, numpy, {w} worker{'s' if w > 1 else ''}", _file_path(shards, submission, w, args.repeat, "numpy"), n)


if __name__ == "__main__":
    main()
