"""Seconds per scenario for the WOSAC metrics, with a breakdown by stage.

Usage:
  python benchmarks/score_speed.py [--scenarios FILE] [--submission FILE] [--repeat N]

Defaults to the real scenario 637f20cafde22ff8 and its official 32-rollout
test submission from ../shared. Prints the median (and the fastest) over
`--repeat` runs of each stage (parse, arrays, each feature family,
estimators) on one core, scenarios per second, and peak RSS. Like the CLI,
it keeps freed memory for reuse (`wosac_eval.runtime.allocator`); `--system-malloc`
measures with glibc's default thresholds instead.
"""
from __future__ import annotations

import argparse
import resource
import statistics
import time
from pathlib import Path


from wosac_eval.runtime.allocator import keep_freed_memory
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.features import box_geometry, interaction, kinematics, metric_features as mf, road_edge, traffic_lights
from wosac_eval.metrics.config import load_config
from wosac_eval.metrics.scenario_metrics import scenario_metrics
from wosac_eval.parse.tfrecord import read_records
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2

from bench_env import SHARED


def _timed(stages, name, fn, *args):
    t = time.perf_counter()
    out = fn(*args)
    stages[name] = stages.get(name, 0.0) + time.perf_counter() - t
    return out


def _features(stages, scen, traj, ctx):
    n_eval = len(scen.evaluated_ids)
    e = slice(0, n_eval)
    F = mf.FUTURE
    fut = lambda a: a[..., F]
    _timed(stages, "features: kinematics", kinematics.kinematic_features,
           traj.x[:, e], traj.y[:, e], traj.z[:, e], traj.heading[:, e], 0.1)
    cos_h, sin_h = _timed(stages, "features: box corners (sin/cos)", box_geometry.heading_cos_sin, traj.heading, F)
    _timed(stages, "features: nearest object / collision", interaction.distance_to_nearest_object,
           fut(traj.x), fut(traj.y), fut(traj.length), fut(traj.width), cos_h, sin_h, fut(traj.valid), n_eval)
    _timed(stages, "features: time to collision", interaction.time_to_collision, traj.x, traj.y, traj.length,
           traj.width, traj.heading, traj.valid, n_eval, 0.1, F)
    corners = mf._box_corners_3d(traj, cos_h, sin_h, e, F)
    _timed(stages, "features: road edge / offroad", road_edge.distance_to_road_edge, corners,
           fut(traj.valid[:, e]), ctx.road_edges)
    sig = scen.signals
    _timed(stages, "features: red light", traffic_lights.red_light_violation, traj.x[:, e, 10:], traj.y[:, e, 10:],
           traj.valid[:, e, 10:], ctx.lanes, None if sig is None else mf._signals_from(sig, 10))


def run_once(scenario_bytes: bytes, submission_bytes: bytes, config) -> dict:
    stages: dict[str, float] = {}
    scenario = _timed(stages, "parse: protobuf", scenario_pb2.Scenario.FromString, scenario_bytes)
    submission = _timed(stages, "parse: protobuf", sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString,
                        submission_bytes)
    rollouts = submission.scenario_rollouts[0]
    scen = _timed(stages, "arrays: scenario", scenario_arrays, scenario)
    ro = _timed(stages, "arrays: rollouts", rollout_arrays, rollouts)
    ctx = _timed(stages, "map index (k-d trees)", mf.map_context, scen)
    # The breakdown runs the kernels once more on the rollouts alone; the
    # end-to-end figure below is the real pipeline.
    sim_traj = mf.simulated_trajectories(scen, ro)
    _features(stages, scen, sim_traj, ctx)
    t = time.perf_counter()
    log, sim = mf.scenario_features(scen, ro, ctx)
    end_to_end_features = time.perf_counter() - t
    _timed(stages, "estimators + metrics", scenario_metrics, config, log, sim)
    stages["total (parse + arrays + features(log+sim) + metrics)"] = (
        stages["parse: protobuf"] + stages["arrays: scenario"] + stages["arrays: rollouts"]
        + stages["map index (k-d trees)"] + end_to_end_features + stages["estimators + metrics"])
    return stages


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", default=str(SHARED / "womd" / "motion_data_one_scenario.tfrecord"))
    p.add_argument("--submission", default=str(SHARED / "golden" / "637f20cafde22ff8__official_test_submission.binproto"))
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--config", default="2025")
    p.add_argument("--system-malloc", action="store_true", help="leave glibc's malloc thresholds as they are")
    args = p.parse_args()
    allocator = "system malloc" if args.system_malloc else (
        "freed memory kept for reuse" if keep_freed_memory() else "system malloc (setting unavailable)")
    submission_bytes = Path(args.submission).read_bytes()
    wanted = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(submission_bytes).scenario_rollouts[0].scenario_id
    scenario_bytes = next(r for r in read_records(args.scenarios)
                          if scenario_pb2.Scenario.FromString(r).scenario_id == wanted)
    config = load_config(args.config)
    run_once(scenario_bytes, submission_bytes, config)  # warm-up
    runs = [run_once(scenario_bytes, submission_bytes, config) for _ in range(args.repeat)]
    print(f"scenario {wanted}, {args.repeat} runs, seconds per scenario on one core ({allocator}):")
    print(f"  {'stage':<58} {'median':>8} {'fastest':>8}")
    for name in runs[0]:
        values = [r[name] for r in runs]
        print(f"  {name:<58} {statistics.median(values):8.4f} {min(values):8.4f}")
    total = statistics.median(r[list(runs[0])[-1]] for r in runs)
    print(f"  scenarios per second: {1 / total:.2f}")
    print(f"  speed-up over the official 52 s/scenario: {52 / total:.0f}x")
    print(f"  peak RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
