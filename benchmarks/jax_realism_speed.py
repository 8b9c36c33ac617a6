"""Realism in a training loop (`wosac_eval.jax_realism`): scenes per second over a batch sweep, XLA's cost per scene.

What a training loop does, and only that, in the main rows: `prepare` a scene set once (timed
separately), keep the rollouts resident on the device, and call a jitted step that takes `prepared`
as an argument, `jax.jit(step)(prepared, rollouts, shift)`, with `step` returning the meta-metric
of `realism` on the rollouts moved by `shift` (new rollouts every call, as a training step scores
its own). For each batch size of `--scenes` (the prepared scenes repeated on the device, scene by
scene, up to that many) and each mode: float32 (x64 off: JAX's defaults, no XLA flag, as a training
loop runs) and exact (traced with x64 on).

The closed-over pattern, `jax.jit(lambda rollouts, shift: step(prepared, rollouts, shift))`, which
makes the prepared scenes constants of the compiled program, has its own labelled rows (float32
mode) at the sizes of `--closed-over` (default: the smallest of `--scenes`; it is the pattern to
avoid: at 2,048 real scenes on an H200 it captured 7.88 GB of constants and had not compiled after
220 s).

Every row prints: the compile time of its program (`jitted.lower(...).compile()`), the median
seconds per call over `--repeat` calls after one warm-up call, scenes per second, the projection for
the 44,097-scene validation set, and XLA's cost analysis of the compiled program per scene
(`compiled.cost_analysis()`: "flops" and "bytes accessed"; with the host search the callbacks' work
on the host is not in it, and a loop body counts once), and where the device reports it
(`memory_stats()`; not on a CPU) the peak device memory per scene so far. Pure JAX: nothing here
is specific to a CPU.

`--search host,device` times each of `prepare`'s searches (default "auto": the host's pruned search
on a CPU, the device's fixed-shape one on an accelerator). `--womd` takes the real WOMD scenes of
the reference material (`../shared/womd`, or WOSAC_SHARED) as the scene set to repeat, else
`--distinct` synthetic scenes. `--file-path` adds the file path's rows for the distinct scenes
(`score_submission`, jax and numpy backends, in fresh processes: parsing, validation and host
preparation included), for comparison.

`--cost-only` sizes are compiled from the arrays' shapes alone and print XLA's cost analysis only (no
call, no arrays: 2,048 real scenes' would not fit a small machine's memory).

Usage: python benchmarks/jax_realism_speed.py [--scenes 16,64,256] [--repeat 3] [--distinct 8 | --womd]
                                              [--search auto|host|device|host,device] [--modes float32,exact]
                                              [--closed-over 16] [--cost-only 2048] [--file-path [--workers 2]]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import jax
import numpy as np
from bench_env import SHARED, VALIDATION_SET, median_seconds

from support.tiling import tiled, tiled_rollouts
from wosac_eval import jax_realism
from wosac_eval.backends.realism_inputs import CLOSED_OVER_WARNING_BYTES
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

    done = subprocess.run(
        [
            sys.executable,
            "-c",
            _FILE_PATH_CHILD,
            ",".join(map(str, shards)),
            str(submission),
            str(workers),
            str(repeat),
            backend,
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    return float(done.stdout.split()[-1])


def _peak_device_bytes() -> int | None:
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use")


def step(prepared, rollouts: dict, shift):
    """A training step's realism: the meta-metric per scene of the rollouts moved by `shift` metres."""
    moved = dict(rollouts, x=rollouts["x"] + shift)
    return jax_realism.realism(prepared, **moved)["metametric"]


def cost_per_scene(compiled, num_scenes: int) -> tuple[float, float]:
    """XLA's (flops, bytes accessed) of a compiled program, per scene."""
    cost = compiled.cost_analysis()
    if isinstance(cost, (list, tuple)):  # older JAX: one dict per program
        cost = cost[0]
    return cost.get("flops", float("nan")) / num_scenes, cost.get("bytes accessed", float("nan")) / num_scenes


HEADER = (
    f"{'path':62s} {'scenes':>6s} {'compile s':>9s} {'s/call':>8s} {'scenes/s':>9s} {'44,097':>8s} "
    f"{'flops/scene':>11s} {'bytes/scene':>11s} {'peak MiB/scene':>14s}"
)


def row(label: str, num_scenes: int, compile_s: float, seconds: float | None, cost=(float("nan"),) * 2) -> None:
    """One row of the table; `seconds` None for a program compiled only (no call: no time, no peak memory)."""
    peak = _peak_device_bytes() if seconds is not None else None
    peak_text = "-" if peak is None else f"{peak / num_scenes / 2**20:.1f}"
    timing = (
        f"{'-':>8s} {'-':>9s} {'-':>8s}"
        if seconds is None
        else f"{seconds:8.3f} {num_scenes / seconds:9.1f} {VALIDATION_SET * seconds / num_scenes / 60:6.1f} m"
    )
    print(
        f"{label:62s} {num_scenes:6d} {compile_s:9.1f} {timing} {cost[0]:11.2e} {cost[1]:11.2e} {peak_text:>14s}",
        flush=True,
    )


def timed_calls(compiled, args_of, repeat: int) -> float:
    """Median seconds of `compiled(*args_of(k))` on new shifts, after one warm-up call."""
    shift = {"k": 0}

    def call():
        shift["k"] += 1  # new rollouts every step
        jax.block_until_ready(compiled(*args_of(np.float32(0.01 * shift["k"]))))

    return median_seconds(call, repeat, warmup=1)


def compiled_step(prepared, rollouts):
    """(`jax.jit(step)` compiled for `prepared` and the rollouts as arguments, the seconds it took); arrays
    or their shapes (`jax.ShapeDtypeStruct`)."""
    start = time.perf_counter()
    compiled = jax.jit(step).lower(prepared, rollouts, np.float32(0)).compile()
    return compiled, time.perf_counter() - start


def in_the_loop(prepared, rollouts, mode: str, repeat: int) -> tuple[float, float, tuple]:
    """(compile s, s/call, cost per scene) of `jax.jit(step)` with `prepared` and the rollouts as arguments."""
    with jax.enable_x64(mode == "exact"):
        compiled, compile_s = compiled_step(prepared, rollouts)
        seconds = timed_calls(compiled, lambda shift: (prepared, rollouts, shift), repeat)
    return compile_s, seconds, cost_per_scene(compiled, prepared.num_scenes)


def cost_only(prepared, arrays, size: int, mode: str) -> tuple[float, tuple]:
    """(compile s, cost per scene) of the in-loop program for `size` scenes, lowered from their shapes
    alone: no arrays made, no call (sizes whose arrays a machine's memory cannot hold)."""
    batch, rollouts = tiled(prepared, size, abstract=True), tiled_rollouts(arrays, size, abstract=True)
    with jax.enable_x64(mode == "exact"):
        compiled, compile_s = compiled_step(batch, rollouts)
    return compile_s, cost_per_scene(compiled, size)


def closed_over(prepared, rollouts, repeat: int) -> tuple[float, float, tuple, bool]:
    """The same, float32 mode, with `prepared` closed over (constants of the program); and whether
    `realism` warned about it (it warns once per process)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        start = time.perf_counter()
        compiled = jax.jit(lambda r, shift: step(prepared, r, shift)).lower(rollouts, np.float32(0)).compile()
        compile_s = time.perf_counter() - start
    warned = any("closes over" in str(w.message) for w in caught)
    seconds = timed_calls(compiled, lambda shift: (rollouts, shift), repeat)
    return compile_s, seconds, cost_per_scene(compiled, prepared.num_scenes), warned


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


def _arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="16,64,256", help="comma-separated scenes per call (the batch sweep)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--distinct", type=int, default=8, help="distinct synthetic scenes, repeated to each batch")
    parser.add_argument("--womd", action="store_true", help="repeat the real WOMD scenes of ../shared/womd instead")
    parser.add_argument("--search", default="auto", help="comma-separated searches of `prepare` to time")
    parser.add_argument("--modes", default="float32,exact", help="comma-separated modes of the main rows")
    parser.add_argument(
        "--closed-over",
        default=None,
        help="comma-separated batch sizes of the closed-over rows (default: the smallest; 0: none)",
    )
    parser.add_argument(
        "--cost-only",
        default="",
        help="comma-separated batch sizes whose program is only compiled, from shapes, for XLA's cost analysis",
    )
    parser.add_argument("--file-path", action="store_true", help="also the file path's rows, for the distinct scenes")
    parser.add_argument("--workers", type=int, default=2, help="numpy workers of the file path's rows")
    return parser.parse_args()


def main() -> None:
    args = _arguments()
    sizes = [int(n) for n in args.scenes.split(",")]
    closed_sizes = [min(sizes)] if args.closed_over is None else [int(n) for n in args.closed_over.split(",") if int(n)]
    if args.womd:
        scenarios, shards = womd_scenarios()
        what = f"{len(scenarios)} real WOMD scenes"
    else:
        scenarios, shards = scenes.generate_scenes(args.distinct, seed=7), None
        what = f"{len(scenarios)} synthetic scenes"
    print(
        f"device: {jax.devices()[0]} (JAX {jax.__version__}); {what} repeated to {args.scenes} per call, "
        f"IDM rollouts (32 each), sim agents",
        flush=True,
    )
    rollouts = [policy_rollouts(sc, "idm") for sc in scenarios]
    n = len(scenarios)
    for search in args.search.split(","):
        start = time.perf_counter()
        prepared = jax_realism.prepare(scenarios, search=search)
        prepare_s = time.perf_counter() - start
        arrays = jax_realism.stack_rollouts(prepared, rollouts)
        print(
            f"prepare (once per scene set), {prepared.search} search: {prepare_s:.2f} s "
            f"({prepare_s / n * 1e3:.0f} ms/scene), {len(prepared.groups)} group(s)",
            flush=True,
        )
        print(HEADER, flush=True)
        for size in sorted(set(sizes) | set(closed_sizes)):
            _size_rows(prepared, arrays, size, args, (size in sizes, size in closed_sizes))
        for size in [int(n) for n in args.cost_only.split(",") if n]:
            for mode in args.modes.split(","):
                compile_s, cost = cost_only(prepared, arrays, size, mode)
                row(f"compiled only, {prepared.search} search, {mode} mode", size, compile_s, None, cost)
    if args.file_path:
        _file_path_rows(scenarios, shards, args)


def _size_rows(prepared, arrays, size: int, args: argparse.Namespace, which: tuple[bool, bool]) -> None:
    """The rows of one batch size: in the loop in each mode, and/or closed over (`which`)."""
    in_loop, closed = which
    try:
        batch = tiled(prepared, size)  # gathered on the device
        resident = jax.device_put(tiled_rollouts(arrays, size))  # the rollouts live on the device
        jax.block_until_ready(resident)
        if in_loop:
            for mode in args.modes.split(","):
                compile_s, seconds, cost = in_the_loop(batch, resident, mode, args.repeat)
                row(
                    f"in the loop, {prepared.search} search, {mode} mode, prepared an argument",
                    size,
                    compile_s,
                    seconds,
                    cost,
                )
        if closed:
            compile_s, seconds, cost, warned = closed_over(batch, resident, args.repeat)
            row(f"CLOSED OVER (constants), {prepared.search} search, float32", size, compile_s, seconds, cost)
            constants = sum(leaf.nbytes for leaf in jax.tree_util.tree_leaves(batch))
            why = (
                "yes"
                if warned
                else "no, under its threshold"
                if constants <= CLOSED_OVER_WARNING_BYTES
                else "no, it warns once per process"
            )
            print(
                f"  closed over: {constants / 1e6:.1f} MB of prepared arrays became constants; realism warned: {why}",
                flush=True,
            )
    except Exception as error:  # a batch too big for the device: say so, go on with the others
        print(f"batch of {size} scenes: {type(error).__name__}: {str(error).splitlines()[0][:200]}", flush=True)
    # The batch's device arrays go with this call, before the next size's are made.


def _file_path_rows(scenarios: list, shards: list | None, args: argparse.Namespace) -> None:
    """The file path's rows for the distinct scenes: --backend jax, and numpy in 1 and --workers processes."""
    n = len(scenarios)
    with tempfile.TemporaryDirectory() as tmp:
        if shards is None:
            shards = scenes.write_scenario_shards(scenarios, Path(tmp) / "scenarios")
        submission = make_submission(shards, "idm", Path(tmp) / "idm.tar.gz")
        print(f"file path, {n} distinct scenes per call:", flush=True)
        paths = [("--backend jax (exact)", 1, "jax"), ("numpy, 1 worker", 1, "numpy")]
        if args.workers > 1:
            paths.append((f"numpy, {args.workers} workers", args.workers, "numpy"))
        for label, workers, backend in paths:
            row(
                f"file path, {label}",
                n,
                float("nan"),
                _file_path(shards, submission, workers, args.repeat, backend),
            )


if __name__ == "__main__":
    main()
