"""The official API's `compute_scenario_metrics_for_bundle` through wosac-eval against `wosac_eval.score_scenario`.

Usage:
  python benchmarks/compat_bundle_speed.py [--scenarios FILE] [--submission FILE] [--repeat N]

Users of the official API call `metrics.compute_scenario_metrics_for_bundle(config, scenario, rollouts)` in a loop
over the validation set: this times it, called through the official names (`import
wosac_eval.compat.official_names`, then `waymo_open_dataset.wdl_limited.sim_agents_metrics.metrics`), and the
library's `score_scenario` on the same parsed scenario, rollouts and config message, the two interleaved, on the
real scene 637f20cafde22ff8 and its official 32-rollout test submission (../shared). Prints the median seconds of
each over `--repeat` runs after a warm-up, and their ratio (the goal: at most 1.2).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import wosac_eval.compat.official_names  # noqa: F401  (the official names, as a user's program opts in)

# isort: split
from bench_env import SHARED
from waymo_open_dataset.wdl_limited.sim_agents_metrics import metrics

from wosac_eval import read_scenarios, score_scenario
from wosac_eval.compat.submission_specs import ChallengeType
from wosac_eval.protos import sim_agents_submission_pb2


def interleaved_medians(calls: dict, repeat: int) -> dict:
    """Median wall seconds of each call, run in turn `repeat` times after one warm-up each."""
    for call in calls.values():
        call()
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeat):
        for name, call in calls.items():
            start = time.perf_counter()
            call()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", default=str(SHARED / "womd" / "motion_data_one_scenario.tfrecord"))
    p.add_argument(
        "--submission", default=str(SHARED / "golden" / "637f20cafde22ff8__official_test_submission.binproto")
    )
    p.add_argument("--repeat", type=int, default=9)
    args = p.parse_args()
    submission = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(Path(args.submission).read_bytes())
    rollouts = submission.scenario_rollouts[0]
    scenario = next(s for s in read_scenarios(args.scenarios) if s.scenario_id == rollouts.scenario_id)
    config = metrics.load_metrics_config(ChallengeType.SIM_AGENTS)
    official = metrics.compute_scenario_metrics_for_bundle(config, scenario, rollouts)
    library = score_scenario(scenario, rollouts, config)
    assert official.metametric == library["metametric"]  # the same numbers: only the time is compared
    medians = interleaved_medians(
        {
            "compute_scenario_metrics_for_bundle": lambda: metrics.compute_scenario_metrics_for_bundle(
                config, scenario, rollouts
            ),
            "score_scenario": lambda: score_scenario(scenario, rollouts, config),
        },
        args.repeat,
    )
    print(
        f"scenario {scenario.scenario_id} ({len(scenario.tracks)} tracks, {len(rollouts.joint_scenes)} rollouts), "
        f"median of {args.repeat} interleaved runs after a warm-up, one core:"
    )
    for name, seconds in medians.items():
        print(f"  {name:<38} {seconds * 1000:8.1f} ms")
    ratio = medians["compute_scenario_metrics_for_bundle"] / medians["score_scenario"]
    print(f"ratio compat / library: {ratio:.3f} (goal: at most 1.2)")


if __name__ == "__main__":
    main()
