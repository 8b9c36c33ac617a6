"""`wosac-eval score --backend jax` on the demo, a first run and a later one, with and without the traced
programs kept (backends/program_cache.py): wall seconds of each CLI run, and whether the results agree.

Each case runs the command as a user does, in a fresh process, with its own empty cache folder
(XDG_CACHE_HOME) and no JAX_COMPILATION_CACHE_DIR, so XLA's compiled programs go to the CLI's own
folder (`jax-compiled`):
  * traced programs kept: the first run (nothing kept), then a second run (both kept);
  * traced programs off (WOSAC_JAX_PROGRAM_CACHE=off): the first run, then a second (compiled ones kept).
The demo (10 scenes, 10 size buckets) is written once by `wosac-eval demo` into a scratch folder.

Usage: python benchmarks/jax_program_cache.py [--runs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CLI = [sys.executable, "-m", "wosac_eval.fronts.cli"]


def score(work: Path, cache: Path, out: str, programs: bool) -> float:
    """Seconds of one `wosac-eval score --backend jax` of the demo's IDM submission."""
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "WOSAC_JAX_PROGRAM_CACHE")}
    env["XDG_CACHE_HOME"] = str(cache)
    if not programs:
        env["WOSAC_JAX_PROGRAM_CACHE"] = "off"
    demo = work / "demo"
    args = ["score", "--scenarios", str(demo / "scenarios"), "--submission", str(demo / "submissions" / "idm.tar.gz")]
    start = time.perf_counter()
    subprocess.run([*CLI, *args, "--backend", "jax", "-o", str(work / out)], env=env, check=True, capture_output=True)
    return time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2, help="runs per case, each after the one before")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        subprocess.run([*CLI, "demo", "--workdir", str(work / "demo")], check=True, capture_output=True)
        rows, results = [], []
        for programs in (True, False):
            cache = work / ("cache-kept" if programs else "cache-off")
            for run in range(1, args.runs + 1):
                out = f"{'kept' if programs else 'off'}-{run}.json"
                seconds = score(work, cache, out, programs)
                rows.append(("kept" if programs else "off", run, seconds))
                results.append(json.loads((work / out).read_text()))
        print("score --backend jax, the demo's 10 scenes (10 buckets), each run in a fresh process")
        print(f"{'traced programs':>16} {'run':>4} {'seconds':>8}")
        for case, run, seconds in rows:
            print(f"{case:>16} {run:>4} {seconds:8.1f}")
        same = all(
            r["scenarios"] == results[0]["scenarios"] and r["aggregate"] == results[0]["aggregate"] for r in results
        )
        print(f"every run's per-scene metrics and aggregate identical: {same}")
        return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
