"""What the per-scenario analysis (criticality, SDC driving scores, per-type realism) adds to scoring.

`score_submission` scores every scenario with `analysis=True`; the goal is at
most 10% more time than the official metrics alone. For each scene, on one
core (`OMP_NUM_THREADS=1`), the same warm-up (one call of each) and the same
`--repeat` timed calls, alternated: `score_scenario(..., analysis=False)` and
`score_scenario(..., analysis=True)` from parsed arrays, and the analysis parts
alone. Prints per-scene medians and the overall ratio.

Scenes: the 10 demo scenes (constant-velocity rollouts, sim agents) and, with
../shared, the real scene 637f20cafde22ff8; `--challenge scenario_gen` scores
the scenario-gen baseline instead.

Then end to end, as `wosac-eval score` runs (index, validation, parsing,
scoring, assembly; one worker): `score_submission(..., analysis=False)` and
`analysis=True` on the demo scenes with the IDM baseline, alternated, the same
repetitions each.

Usage: python benchmarks/analysis_cost.py [--repeat 5] [--challenge sim_agents|scenario_gen]
"""

from __future__ import annotations

import argparse
import os
import statistics

os.environ.setdefault("OMP_NUM_THREADS", "1")

from bench_env import SHARED, median_seconds  # noqa: E402

from wosac_eval.analysis.criticality_scores import scenario_criticality  # noqa: E402
from wosac_eval.arrays.scenario import scenario_arrays  # noqa: E402
from wosac_eval.features.metric_features import map_context  # noqa: E402
from wosac_eval.parse.scenarios import read_scenarios  # noqa: E402
from wosac_eval.runtime.allocator import keep_freed_memory  # noqa: E402
from wosac_eval.scoring.scenario import score_scenario  # noqa: E402
from wosac_eval.sim import scenes  # noqa: E402
from wosac_eval.sim.baselines import policy_rollouts  # noqa: E402


def _scenes() -> list:
    out = scenes.generate_scenes(10, seed=0)
    real = SHARED / "womd"
    if real.exists():
        out += [s for s in read_scenarios(real) if s.scenario_id == "637f20cafde22ff8"]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--challenge", choices=("sim_agents", "scenario_gen"), default="sim_agents")
    args = parser.parse_args()
    keep_freed_memory()
    policy = "constant_velocity" if args.challenge == "sim_agents" else "log_replay_noise"
    total_plain = total_full = 0.0
    print(
        f"{'scenario':36s} {'objects':>7s} {'metrics ms':>11s} {'+analysis ms':>13s} {'ratio':>6s} "
        f"{'criticality ms':>15s}"
    )
    for scenario in _scenes():
        arrays = scenario_arrays(scenario)
        rollouts = policy_rollouts(scenario, policy, challenge=args.challenge)
        calls = {
            "plain": lambda: score_scenario(arrays, rollouts, challenge=args.challenge),
            "full": lambda: score_scenario(arrays, rollouts, challenge=args.challenge, analysis=True),
            "criticality": lambda: scenario_criticality(arrays, map_context(arrays)),
        }
        for fn in calls.values():  # the same warm-up for each
            fn()
        plain, full = [], []
        for _ in range(args.repeat):  # alternated, so that drift affects both alike
            plain.append(median_seconds(calls["plain"], 1))
            full.append(median_seconds(calls["full"], 1))
        crit = median_seconds(calls["criticality"], args.repeat)
        p, f = statistics.median(plain), statistics.median(full)
        total_plain += p
        total_full += f
        print(
            f"{scenario.scenario_id[:36]:36s} {arrays.sim_agent_ids.size:7d} {p * 1e3:11.1f} {f * 1e3:13.1f} "
            f"{f / p:6.3f} {crit * 1e3:15.1f}"
        )
    print(
        f"\nall scenes ({args.challenge}): metrics {total_plain:.3f} s, with the analysis {total_full:.3f} s: "
        f"+{(total_full / total_plain - 1) * 100:.1f}% (goal <= 10%)"
    )
    end_to_end(args.repeat, args.challenge)


def end_to_end(repeat: int, challenge: str) -> None:
    import tempfile
    from pathlib import Path

    from wosac_eval.scoring.submission import score_submission
    from wosac_eval.sim.baselines import make_submission

    with tempfile.TemporaryDirectory() as tmp:
        shards = scenes.write_scenario_shards(scenes.generate_scenes(10, seed=0), Path(tmp) / "scenarios")
        policy = "idm"
        submission = make_submission(shards, policy, Path(tmp) / "idm.tar.gz", challenge=challenge)
        run = {
            flag: (lambda flag=flag: score_submission(shards, submission, challenge=challenge, analysis=flag))
            for flag in (False, True)
        }
        for fn in run.values():
            fn()
        times = {False: [], True: []}
        for _ in range(repeat):
            for flag, fn in run.items():
                times[flag].append(median_seconds(fn, 1))
        off, on = (statistics.median(times[f]) for f in (False, True))
        print(
            f"end to end, score_submission of 10 demo scenes ({challenge}, {policy}, 1 worker): "
            f"{off / 10 * 1e3:.1f} ms/scenario without the analysis, {on / 10 * 1e3:.1f} with it: "
            f"+{(on / off - 1) * 100:.1f}%"
        )


if __name__ == "__main__":
    main()
