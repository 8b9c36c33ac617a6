"""The speed report of issue 5 in one run: every figure the targets ask for.

Sections (each measured in this run, side by side where compared):
  1. one real scenario (637f20cafde22ff8, its official 32-rollout submission)
     on one core, steady state, with the stage breakdown (benchmarks/score_speed.py);
  2. cost against the number of objects and of evaluated objects
     (benchmarks/score_objects.py);
  3. whole submissions through `score_submission` (validation included) with
     1 and 2 worker processes: seconds per scenario, scenarios per second,
     speed-up, peak RSS at two submission sizes, identical results
     (benchmarks/score_scaling.py);
  4. numpy against jax on this machine's CPU (benchmarks/score_backends.py),
     when JAX is installed (`pip install '.[jax]'`).
Each section runs in its own process, so one section's memory or threads do
not colour another's. Needs ../shared (the real scenario and submission).

Usage:
  python benchmarks/speed_report.py [--sizes 100 500] [--repeat 15] [--skip objects jax]
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _section(title: str, script: str, *args: str, env: dict | None = None) -> int:
    print(f"\n== {title} ==\n$ python benchmarks/{script} {' '.join(args)}", flush=True)
    start = time.perf_counter()
    code = subprocess.call([sys.executable, str(HERE / script), *args],
                           env={**os.environ, **(env or {})})
    print(f"({time.perf_counter() - start:.0f} s)", flush=True)
    return code


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", nargs="+", default=["100", "500"], help="submission sizes for section 3")
    p.add_argument("--repeat", default="15", help="runs of the single-scenario measurement")
    p.add_argument("--skip", nargs="*", default=[], choices=["scenario", "objects", "workers", "jax"])
    args = p.parse_args()
    one_core = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    print(f"machine: {os.cpu_count()} cores; python {sys.version.split()[0]}")
    failed = 0
    if "scenario" not in args.skip:
        failed |= _section("1. One scenario, one core (target: at most 0.1 s)", "score_speed.py",
                           "--repeat", args.repeat, env=one_core)
    if "objects" not in args.skip:
        failed |= _section("2. Cost against objects x evaluated objects, one core", "score_objects.py",
                           env=one_core)
    if "workers" not in args.skip:
        failed |= _section("3. Whole submissions: workers and peak memory", "score_scaling.py",
                           "--sizes", *args.sizes, "--workers", "1", "2", env=one_core)
    if "jax" not in args.skip:
        if importlib.util.find_spec("jax") is None:
            print("\n== 4. numpy vs jax ==\nskipped: JAX is not installed (pip install '.[jax]')")
        else:
            failed |= _section("4. numpy vs jax backends (CPU; no GPU on this machine)" if not _has_gpu()
                               else "4. numpy vs jax backends", "score_backends.py")
    return failed


def _has_gpu() -> bool:
    out = subprocess.run([sys.executable, "-c", "import jax; print(jax.default_backend())"],
                         capture_output=True, text=True)
    return out.stdout.strip() not in ("", "cpu")


if __name__ == "__main__":
    sys.exit(main())
