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
import io
import json
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from wosac_eval.parse.tfrecord import read_records, write_records
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2

SHARED = Path(__file__).resolve().parents[2] / "shared"
CASE = "637f20cafde22ff8__official_test_submission"

_RUNNER = """
import json, resource, sys, time
from wosac_eval.metrics.submission import score_submission
t = time.perf_counter()
result = score_submission([sys.argv[1]], sys.argv[2], "2025", workers=int(sys.argv[3]))
elapsed = time.perf_counter() - t
rss = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
print(json.dumps({"elapsed": elapsed, "rss_mib": rss / 1024, "n": result["num_scenarios"],
                  "scenarios": result["scenarios"]}))
"""


def build(n: int, folder: Path) -> tuple[Path, Path]:
    scenario = scenario_pb2.Scenario.FromString(next(iter(read_records(SHARED / "womd" / "motion_data_one_scenario.tfrecord"))))
    golden = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(
        (SHARED / "golden" / f"{CASE}.binproto").read_bytes())
    rollouts = golden.scenario_rollouts[0]
    ids = [f"{scenario.scenario_id}-{i:05d}" for i in range(n)]

    def renamed_scenarios():
        for sid in ids:
            scenario.scenario_id = sid
            yield scenario.SerializeToString()
    scenarios = folder / f"scenarios-{n}.tfrecord"
    write_records(scenarios, renamed_scenarios())
    submission = folder / f"submission-{n}.tar.gz"
    per_shard = 10
    shards = (n + per_shard - 1) // per_shard
    with tarfile.open(submission, "w:gz") as tar:
        for s in range(shards):
            shard = sim_agents_submission_pb2.SimAgentsChallengeSubmission()
            shard.CopyFrom(golden)
            del shard.scenario_rollouts[:]
            for sid in ids[s * per_shard:(s + 1) * per_shard]:
                r = shard.scenario_rollouts.add()
                r.CopyFrom(rollouts)
                r.scenario_id = sid
            data = shard.SerializeToString()
            info = tarfile.TarInfo(f"submission/bench.binproto-{s:05d}-of-{shards:05d}")
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return scenarios, submission


def run(scenarios: Path, submission: Path, workers: int) -> dict:
    out = subprocess.run([sys.executable, "-c", _RUNNER, str(scenarios), str(submission), str(workers)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[20, 100])
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = p.parse_args()
    print(f"{'scenarios':>9} {'workers':>7} {'seconds':>8} {'s/scenario':>10} {'scen/s':>7} "
          f"{'speed-up':>8} {'peak RSS MiB':>12} {'identical':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.sizes:
            scenarios, submission = build(n, Path(tmp))
            baseline = None
            for w in args.workers:
                r = run(scenarios, submission, w)
                baseline = baseline or r
                same = r["scenarios"] == baseline["scenarios"]
                print(f"{n:>9} {w:>7} {r['elapsed']:>8.1f} {r['elapsed'] / n:>10.3f} {n / r['elapsed']:>7.2f} "
                      f"{baseline['elapsed'] / r['elapsed']:>8.2f} {r['rss_mib']:>12.0f} {str(same):>9}", flush=True)


if __name__ == "__main__":
    main()
