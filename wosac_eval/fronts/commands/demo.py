"""`wosac-eval demo [--workdir DIR]`: the whole pipeline on embedded synthetic data, in under a minute.

Generates (or loads from DIR) ten deterministic synthetic scenes, runs each
baseline policy for both challenges (sim agents, then scenario generation),
validates and scores every submission, writes one result JSON per policy under
DIR/results (DIR/results/scenario_gen for scenario gen) and prints a
leaderboard per challenge.

`wosac-eval demo --gate DIR` instead writes two synthetic results of 2000
scenarios (DIR/baseline.json, DIR/new.json) and their comparison report
(DIR/report.html), to try `compare` and `report` without a simulator.

Exit codes: 0 done, 1 a baseline produced an invalid submission (a bug), 2 usage error.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from wosac_eval.challenges import Challenge
from wosac_eval.fronts.demo_pipeline import (
    DEMO_POLICIES,
    DEMO_SCENES,
    DEMO_SEED,
    default_workdir,
    leaderboard,
    run_demo,
)
from wosac_eval.fronts.usage import UsageError, add_challenge, add_workers, check_output_folder

TITLES = {
    "sim_agents": "Sim agents (80 future steps; 2025 config)",
    "scenario_gen": "Scenario generation (all 91 steps of every object; scenario_gen_2025 config)",
}

NAME = "demo"
HELP = "Run every baseline on built-in synthetic scenes, validate, score and print a leaderboard."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Where the demo works, how many scenes, which policies; or --gate for the compare/report demo."""
    parser.add_argument(
        "--workdir",
        type=Path,
        default=None,
        help=f"where scenes, submissions and results go (default {default_workdir()})",
    )
    parser.add_argument("--scenes", type=int, default=DEMO_SCENES, metavar="N", help="number of scenes (default 10)")
    parser.add_argument("--seed", type=int, default=DEMO_SEED, help="scene and rollout seed (default 0)")
    parser.add_argument(
        "--policies",
        nargs="+",
        default=list(DEMO_POLICIES),
        choices=list(DEMO_POLICIES),
        metavar="POLICY",
        help=f"policies to run (default: {' '.join(DEMO_POLICIES)})",
    )
    add_challenge(parser, "which challenge's leaderboard to make (default both)", choices=("both",))
    parser.add_argument(
        "--config",
        default=None,
        help="metrics config (a preset or a textproto path; default: each challenge's current one)",
    )
    add_workers(parser, "processes for simulation and scoring", per_core=True)
    parser.add_argument(
        "--gate",
        type=Path,
        metavar="DIR",
        help="only write two synthetic results and their comparison report into DIR "
        "(baseline.json, new.json, report.html), to try compare and report",
    )


def run_gate_demo(folder: Path) -> int:
    """Synthetic baseline / new results and the report comparing them, in `folder`."""
    import argparse as _argparse

    from wosac_eval.fronts.commands import report
    from wosac_eval.results.synthetic_results import GATE_DEMO_TITLE, write_gate_demo_results

    write_gate_demo_results(folder)
    here = os.getcwd()
    os.chdir(folder)  # so that the report shows short file names
    try:
        parser = _argparse.ArgumentParser()
        report.add_arguments(parser)  # the report command itself, with its defaults
        return report.run(
            parser.parse_args(
                ["new.json", "--html", "report.html", "--compare", "baseline.json", "--title", GATE_DEMO_TITLE]
            )
        )
    finally:
        os.chdir(here)


def run(args: argparse.Namespace) -> int:
    """Generate scenes, run the baselines, score them and print the leaderboard (or the gate demo)."""
    if args.gate is not None:
        check_output_folder(args.gate, "--gate")
        return run_gate_demo(args.gate)
    if args.scenes < 1:
        raise UsageError("--scenes must be >= 1")
    workdir = args.workdir or default_workdir()
    check_output_folder(workdir, "--workdir")
    start = time.perf_counter()
    chosen = tuple(Challenge) if args.challenge == "both" else (args.challenge,)
    tables = []
    try:
        for challenge in chosen:
            rows = run_demo(
                workdir,
                num_scenes=args.scenes,
                seed=args.seed,
                policies=tuple(args.policies),
                config=args.config,
                workers=args.workers,
                challenge=challenge,
            )
            tables.append((challenge, rows))
    except (OSError, ValueError) as error:
        raise UsageError(str(error)) from None
    for challenge, rows in tables:
        print()
        print(TITLES[challenge] if args.config is None else f"{challenge} (config {args.config})")
        print(leaderboard(rows, challenge))
    print()
    for challenge, rows in tables:
        for row in rows:
            if row.valid:
                print(f"{challenge} {row.policy}: results {row.result_json}  submission {row.submission}")
    print(f"total {time.perf_counter() - start:.1f} s")
    return 0 if all(r.valid for _, rows in tables for r in rows) else 1
