"""Scenario Generation: seconds per scenario on one core, peak memory, and where the time goes.

Every object is evaluated over all 91 steps, so a scene costs 10-30x a sim
agents scene. Two workloads, each in a fresh process (one core,
`OMP_NUM_THREADS=1`; one warm-up call, then `--repeat` timed calls):

- the real scene 637f20cafde22ff8 (50 sim agents, 5251 road-edge segments;
  ../shared), with our log-replay scenario-gen baseline;
- the 34-object synthetic scene of `generate_scenes(10, seed=5)` (large
  coordinates), with the same baseline.

Prints the median seconds per scenario (protobuf in, metrics out), the per-stage
breakdown, and the process's peak RSS.

Usage: python benchmarks/scenario_gen_speed.py [--repeat 7]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

from bench_env import SHARED

_CHILD = r"""
import json, resource, statistics, sys, time
from wosac_eval.runtime.allocator import keep_freed_memory
keep_freed_memory()
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.samples import sample_batch
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.features import metric_features as mf
from wosac_eval.features.search import PrunedSearch
from wosac_eval.metrics.config import load_config
from wosac_eval.metrics.scenario_metrics import scenario_metrics
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2
from wosac_eval.scoring.scenario import score_scenario
from wosac_eval.arrays.messages import rollouts_bytes
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import policy_rollouts

which, repeat = sys.argv[1], int(sys.argv[2])
if which == "real":
    scenario = next(s for s, _ in iter_scenarios(sys.argv[3]))
else:
    scenario = scenes.generate_scenes(10, seed=5)[6]
rollouts = policy_rollouts(scenario, "log_replay_noise", challenge="scenario_gen")
raw_scenario = scenario.SerializeToString()
raw_rollouts = rollouts_bytes(rollouts)
config = load_config("scenario_gen_2025")

def end_to_end():
    s = scenario_pb2.Scenario.FromString(raw_scenario)
    r = sim_agents_submission_pb2.ScenarioRollouts.FromString(raw_rollouts)
    return score_scenario(s, r, config, challenge="scenario_gen")

def timed(fn):
    fn()
    runs = []
    for _ in range(repeat):
        t = time.perf_counter(); out = fn(); runs.append(time.perf_counter() - t)
    return statistics.median(runs), out

total, metrics = timed(end_to_end)
stages = {}
s = scenario_pb2.Scenario.FromString(raw_scenario)
r = sim_agents_submission_pb2.ScenarioRollouts.FromString(raw_rollouts)
stages["parse protobufs"], _ = timed(lambda: (scenario_pb2.Scenario.FromString(raw_scenario),
                                             sim_agents_submission_pb2.ScenarioRollouts.FromString(raw_rollouts)))
stages["scenario arrays"], sa = timed(lambda: scenario_arrays(s))
stages["rollout arrays"], ra = timed(lambda: rollout_arrays(r, "scenario_gen"))
stages["samples"], batch = timed(lambda: sample_batch(sa, ra, "scenario_gen"))
stages["map index"], ctx = timed(lambda: mf.map_context(sa))
layout = mf.feature_layout(batch.spec, batch.num_evaluated)
t = mf.trajectory_arrays(batch)
tails = mf.official_tails(batch.trajectories.num_objects, batch.num_evaluated, 91, 0)
search = PrunedSearch(ctx.road_edges, ctx.lanes, mf.signals_from(sa.signals, 0))
stages["features"], per_step = timed(lambda: mf.per_step_features(t, layout, search, tails))
log, sim = mf.metric_features(batch, per_step)
stages["estimators and metrics"], _ = timed(lambda: scenario_metrics(config, log, sim))
print(json.dumps({"scenario": scenario.scenario_id, "objects": int(rollouts.object_id.shape[1]), "segments": int(ctx.road_edges.valid.sum()),
                  "seconds": total, "stages": stages, "metametric": metrics["metametric"],
                  "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=7)
    args = p.parse_args()
    real = SHARED / "womd" / "motion_data_one_scenario.tfrecord"
    rows = [("synthetic", "")] + ([("real", str(real))] if real.exists() else [])
    print(f"Scenario generation, one core, median of {args.repeat} after a warm-up")
    for which, path in rows:
        out = subprocess.run([sys.executable, "-c", _CHILD, which, str(args.repeat), path], capture_output=True,
                             text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
        if out.returncode:
            sys.exit(out.stderr[-2000:])
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"\n{r['scenario']}: {r['objects']} objects (all evaluated), {r['segments']} road-edge segments")
        print(f"  end to end: {r['seconds']:.3f} s per scenario, peak RSS {r['peak_rss_mib']:.0f} MiB, "
              f"meta-metric {r['metametric']:.4f}")
        for stage, seconds in r["stages"].items():
            print(f"    {stage:24s} {seconds:.4f} s")
    if not real.exists():
        print(f"\n(the real scene needs {real}: ../shared, or WOSAC_SHARED)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
