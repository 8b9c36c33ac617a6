"""Scenario Generation: seconds per scenario on one core, peak memory, and where the time goes.

Every object is evaluated over all 91 steps, so a scene costs 10-30x a sim
agents scene. Two workloads, each in a fresh process (one core,
`OMP_NUM_THREADS=1`; one warm-up call, then `--repeat` timed calls):

- the real scene 637f20cafde22ff8 (50 sim agents, 5251 road-edge segments;
  ../shared), with our log-replay scenario-gen baseline;
- the 34-object synthetic scene of `generate_scenes(10, seed=5)` (large
  coordinates), with the same baseline;
- 128 objects: the real scene's tracks valid at step 10 nearest the SDC, and shifted copies of
  them (4 m sideways) up to 128 (`score_objects.scene_with`), with the same baseline.

Prints the median seconds per scenario (protobuf in, metrics out), the per-stage
breakdown, each search's operation count and share of its arithmetic floor
(`stage_timing.py`), the process's peak RSS, and the projection for the
44,097-scenario validation set on 16 and 32 cores from the real scene's cost
(the synthetic one's without ../shared): scenes x seconds / cores, assuming the
linear scaling across worker processes that `ray_scaling.py` measures for Sim Agents.

Usage: python benchmarks/scenario_gen_speed.py [--repeat 7]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

from pathlib import Path

from bench_env import SHARED, VALIDATION_SET
from stage_timing import print_breakdown

HERE = Path(__file__).resolve().parent

_CHILD = r"""
import json, resource, sys
sys.path.insert(0, sys.argv[4])
from wosac_eval.runtime.allocator import keep_freed_memory
keep_freed_memory()
from wosac_eval.metrics.config import load_config
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.arrays.messages import rollouts_bytes
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import policy_rollouts
from stage_timing import stage_breakdown

which, repeat = sys.argv[1], int(sys.argv[2])
if which == "real":
    scenario = next(s for s, _ in iter_scenarios(sys.argv[3]))
elif which == "real-128":
    from score_objects import scene_with
    scenario = scene_with(next(s for s, _ in iter_scenarios(sys.argv[3])), 128, 128)
else:
    scenario = scenes.generate_scene(5, 6)
rollouts = policy_rollouts(scenario, "log_replay_noise", challenge="scenario_gen")
r = stage_breakdown(scenario.SerializeToString(), rollouts_bytes(rollouts), load_config("scenario_gen_2025"),
                    "scenario_gen", repeat)
r["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(r))
"""


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=7)
    args = p.parse_args()
    real = SHARED / "womd" / "motion_data_one_scenario.tfrecord"
    rows = [("synthetic", "")] + ([("real", str(real)), ("real-128", str(real))] if real.exists() else [])
    print(f"Scenario generation, one core, median of {args.repeat} after a warm-up")
    seconds = {}
    for which, path in rows:
        out = subprocess.run(
            [sys.executable, "-c", _CHILD, which, str(args.repeat), path, str(HERE)],
            capture_output=True,
            text=True,
            env={**os.environ, "OMP_NUM_THREADS": "1"},
        )
        if out.returncode:
            sys.exit(out.stderr[-2000:])
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"\n{r['scenario']}: {r['objects']} objects (all evaluated), {r['segments']} road-edge segments")
        print(
            f"  end to end: {r['seconds']:.3f} s per scenario, peak RSS {r['peak_rss_mib']:.0f} MiB, "
            f"meta-metric {r['metametric']:.4f}"
        )
        print_breakdown(r)
        seconds[which] = r["seconds"]
    which = "real" if "real" in seconds else "synthetic"
    print(
        f"\nprojection for the {VALIDATION_SET:,}-scenario validation set from the {which} scene "
        f"({seconds[which]:.3f} s per scenario on one core, linear scaling assumed):"
    )
    for cores in (16, 32):
        print(f"  {cores:2d} cores: {VALIDATION_SET * seconds[which] / cores / 60:6.1f} min")
    if not real.exists():
        print(f"\n(the real scene needs {real}: ../shared, or WOSAC_SHARED)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
