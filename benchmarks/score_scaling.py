"""Whole-submission scoring: seconds per scenario, worker speed-up, peak memory.

Builds an N-scenario scenario set and a sharded .tar.gz submission by
replicating a real scenario and its 32-rollout golden submission under N
scenario ids, then scores it with `wosac-eval score` semantics
(`score_submission`, validation included) in a fresh process per run, with
1 and 2 workers, and at two sizes to show that peak memory does not grow
with the number of scenarios.

Usage:
  python benchmarks/score_scaling.py [--sizes 20 100] [--workers 1 2]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from bench_env import REPO  # noqa: F401  (puts tests/support on the path)
from support.submissions import GOLDEN, WOMD, replicated_submission

CASE = "637f20cafde22ff8__official_test_submission"

_RUNNER = """
import json, resource, sys, time
from wosac_eval.scoring.submission import score_submission
t = time.perf_counter()
result = score_submission([sys.argv[1]], sys.argv[2], "2025", workers=int(sys.argv[3]))
elapsed = time.perf_counter() - t
rss = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
print(json.dumps({"elapsed": elapsed, "rss_mib": rss / 1024, "n": result["num_scenarios"],
                  "scenarios": result["scenarios"]}))
"""


def build(n: int, folder: Path) -> tuple[Path, Path]:
    if not (GOLDEN.is_dir() and WOMD.is_dir()):
        sys.exit(f"needs the reference data in {GOLDEN.parent} (golden/ and womd/)")
    return replicated_submission(folder, n, per_shard=10, case=CASE)


def run(scenarios: Path, submission: Path, workers: int) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", _RUNNER, str(scenarios), str(submission), str(workers)],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[20, 100])
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = p.parse_args()
    print(
        f"{'scenarios':>9} {'workers':>7} {'seconds':>8} {'s/scenario':>10} {'scen/s':>7} "
        f"{'speed-up':>8} {'peak RSS MiB':>12} {'identical':>9}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.sizes:
            scenarios, submission = build(n, Path(tmp))
            baseline = None
            for w in args.workers:
                r = run(scenarios, submission, w)
                baseline = baseline or r
                same = r["scenarios"] == baseline["scenarios"]
                print(
                    f"{n:>9} {w:>7} {r['elapsed']:>8.1f} {r['elapsed'] / n:>10.3f} {n / r['elapsed']:>7.2f} "
                    f"{baseline['elapsed'] / r['elapsed']:>8.2f} {r['rss_mib']:>12.0f} {str(same):>9}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
