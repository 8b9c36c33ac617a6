"""Seconds per scenario for the WOSAC metrics, with a breakdown by stage.

Usage:
  python benchmarks/score_speed.py [--scenarios FILE] [--submission FILE] [--repeat N]

Defaults to the real scenario 637f20cafde22ff8 and its official 32-rollout
test submission from ../shared. Prints the median over `--repeat` runs (after
a warm-up) of scoring end to end (protobuf bytes in, metrics out) and of each
stage (parse, arrays, each search of the features, estimators), scenarios per
second, each search's operation count and share of its arithmetic floor
(`stage_timing.py`), and peak RSS, on one core. Like the CLI, it keeps freed
memory for reuse (`wosac_eval.runtime.allocator`); `--system-malloc` measures
with glibc's default thresholds instead.
"""

from __future__ import annotations

import argparse
import os
import resource
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from wosac_eval.runtime.allocator import keep_freed_memory  # noqa: E402
from wosac_eval.metrics.config import load_config  # noqa: E402
from wosac_eval.parse.tfrecord import read_records  # noqa: E402
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2  # noqa: E402

from bench_env import SHARED  # noqa: E402
from stage_timing import print_breakdown, stage_breakdown  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", default=str(SHARED / "womd" / "motion_data_one_scenario.tfrecord"))
    p.add_argument(
        "--submission", default=str(SHARED / "golden" / "637f20cafde22ff8__official_test_submission.binproto")
    )
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--config", default="2025")
    p.add_argument("--system-malloc", action="store_true", help="leave glibc's malloc thresholds as they are")
    args = p.parse_args()
    allocator = (
        "system malloc"
        if args.system_malloc
        else ("freed memory kept for reuse" if keep_freed_memory() else "system malloc (setting unavailable)")
    )
    submission = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(Path(args.submission).read_bytes())
    rollouts = submission.scenario_rollouts[0]
    raw_scenario = next(
        r
        for r in read_records(args.scenarios)
        if scenario_pb2.Scenario.FromString(r).scenario_id == rollouts.scenario_id
    )
    r = stage_breakdown(raw_scenario, rollouts.SerializeToString(), load_config(args.config), "sim_agents", args.repeat)
    print(
        f"scenario {r['scenario']} ({r['objects']} objects, {r['evaluated']} evaluated, {r['segments']} road-edge "
        f"segments), median of {args.repeat} runs after a warm-up, one core ({allocator}):"
    )
    print(
        f"  end to end (protobuf bytes in, metrics out): {r['seconds']:.4f} s, "
        f"{1 / r['seconds']:.1f} scenarios per second, meta-metric {r['metametric']:.7f}"
    )
    print_breakdown(r)
    print(f"  peak RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
