"""How scoring cost grows with the number of objects and of evaluated objects.

Builds scenarios from the real WOMD scene 637f20cafde22ff8 (../shared) with
16, 32, 64 and 128 sim agents (the agents nearest the SDC; for 128, a shifted
copy of every agent is added) and 4 to all of them evaluated, gives each
32 noisy constant-velocity rollouts, and prints the median seconds per
scenario of `score_scenario` (features of log and rollouts, estimators) on
one core. The map is the scene's own (5251 road-edge segments).

Usage: python benchmarks/score_objects.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from wosac_eval.runtime.allocator import keep_freed_memory
from wosac_eval.challenges import CURRENT_TIME_INDEX
from wosac_eval.scoring.scenario import score_scenario
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2

from bench_env import SHARED


def scene_with(base: scenario_pb2.Scenario, num_agents: int, num_evaluated: int) -> scenario_pb2.Scenario:
    now = CURRENT_TIME_INDEX
    sdc = base.tracks[base.sdc_track_index]
    agents = [t for t in base.tracks if t.states[now].valid]
    centre = np.array([sdc.states[now].center_x, sdc.states[now].center_y])
    agents.sort(key=lambda t: np.hypot(t.states[now].center_x - centre[0], t.states[now].center_y - centre[1]))
    tracks = [scenario_pb2.Track.FromString(t.SerializeToString()) for t in agents[:num_agents]]
    next_id = max(t.id for t in base.tracks) + 1
    while len(tracks) < num_agents:  # shifted copies, 4 m sideways
        copy = scenario_pb2.Track.FromString(tracks[len(tracks) % len(agents)].SerializeToString())
        copy.id, next_id = next_id, next_id + 1
        for s in copy.states:
            s.center_y += 4.0
        tracks.append(copy)
    scene = scenario_pb2.Scenario()
    scene.CopyFrom(base)
    del scene.tracks[:]
    scene.tracks.extend(tracks)
    scene.sdc_track_index = 0
    del scene.tracks_to_predict[:]
    for i in range(1, num_evaluated):
        scene.tracks_to_predict.add(track_index=i)
    return scene


def rollouts_for(scene: scenario_pb2.Scenario, rng: np.random.Generator) -> sim_agents_submission_pb2.ScenarioRollouts:
    now = CURRENT_TIME_INDEX
    out = sim_agents_submission_pb2.ScenarioRollouts(scenario_id=scene.scenario_id)
    t = np.arange(1, 81) * 0.1
    for _ in range(32):
        joint = out.joint_scenes.add()
        for track in scene.tracks:
            s = track.states[now]
            k = 1 + rng.normal(0, 0.1)
            joint.simulated_trajectories.add(
                object_id=track.id,
                center_x=(s.center_x + k * s.velocity_x * t).tolist(),
                center_y=(s.center_y + k * s.velocity_y * t).tolist(),
                center_z=[s.center_z] * 80,
                heading=[s.heading] * 80,
            )
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args()
    keep_freed_memory()  # as the CLI does
    base = next(s for s, _ in iter_scenarios(SHARED / "womd" / "motion_data_one_scenario.tfrecord"))
    rng = np.random.default_rng(0)
    print(f"{'agents':>6} {'evaluated':>9} {'s/scenario':>10} {'eval x agents':>13}")
    for num_agents in (16, 32, 64, 128):
        for num_evaluated in sorted({4, 8, 16, num_agents}):
            if num_evaluated > num_agents:
                continue
            scene = scene_with(base, num_agents, num_evaluated)
            rollouts = rollouts_for(scene, rng)
            score_scenario(scene, rollouts)
            times = []
            for _ in range(args.repeat):
                t = time.perf_counter()
                score_scenario(scene, rollouts)
                times.append(time.perf_counter() - t)
            print(
                f"{num_agents:>6} {num_evaluated:>9} {statistics.median(times):>10.3f} "
                f"{num_agents * num_evaluated:>13}",
                flush=True,
            )


if __name__ == "__main__":
    main()
