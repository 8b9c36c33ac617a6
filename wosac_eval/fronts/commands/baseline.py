"""`wosac-eval baseline --scenarios PATH... --policy NAME --output submission.tar.gz`.

Runs a baseline sim-agent policy on every scenario and writes a submission in
the official layout (`<method>.binproto-0000k-of-0000n` shards with complete
metadata) as a .tar.gz, a .tar, or a folder; then validates it.

Exit codes: 0 written and valid, 1 written but invalid (a bug: please report),
2 usage error (unknown policy, missing or unreadable scenarios).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from wosac_eval.fronts.usage import UsageError, add_challenge, add_scenarios, add_workers, check_output_folder
from wosac_eval.sim.policies import POLICIES

NAME = "baseline"
HELP = "Write a baseline submission (constant velocity, noisy log replay or IDM lane following) for a scenario set."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The scenario set, the policy, where to write, and the submission metadata."""
    add_scenarios(parser, "synthetic or real WOMD")
    parser.add_argument(
        "--policy",
        required=True,
        choices=sorted(POLICIES),
        help="constant_velocity | log_replay_noise (needs the logged future) | idm",
    )
    add_challenge(
        parser,
        "sim_agents (80 future steps; default) or scenario_gen (all 91 steps with box sizes and object types: the "
        "policy's future after the logged or straight-line history)",
    )
    parser.add_argument(
        "--output",
        required=True,
        metavar="PATH",
        help="submission to write: NAME.tar.gz, NAME.tar, or a folder of shards",
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed of the rollouts (default 0)")
    parser.add_argument("--shards", type=int, default=4, metavar="N", help="number of binproto shards (default 4)")
    add_workers(parser, "simulation processes", per_core=True)
    meta = parser.add_argument_group("submission metadata")
    meta.add_argument("--method-name", help="unique_method_name (default: the policy name)")
    meta.add_argument("--account-name", default="demo@example.com", help="the email registered at waymo.com/open")
    meta.add_argument("--authors", nargs="+", default=["wosac-eval demo"])
    meta.add_argument("--affiliation", default="wosac-eval")
    meta.add_argument("--description", help="default: a one-line description of the policy")
    meta.add_argument("--method-link", default="https://github.com/waymo-research/waymo-open-dataset")


def run(args: argparse.Namespace) -> int:
    """Simulate every scenario, write the shards, validate the result; 0 valid, 1 invalid (a bug), 2 usage error."""
    # Here, not at the top: `wosac-eval --help` imports every command, and these load the scoring stack.
    from wosac_eval.arrays.submission_writer import SubmissionMetadata
    from wosac_eval.parse.errors import ParseError
    from wosac_eval.sim.baselines import DESCRIPTIONS, simulate_rollouts, write_submission
    from wosac_eval.validate import validate_submission

    if args.shards < 1:
        raise UsageError("--shards must be >= 1")
    # An archive's folder, or the shard folder, is created when missing: it must be creatable.
    archive = str(args.output).endswith((".tar.gz", ".tgz", ".tar"))
    check_output_folder(Path(args.output).parent if archive else args.output, "--output")
    metadata = SubmissionMetadata(
        unique_method_name=args.method_name or args.policy.replace("_", "-"),
        account_name=args.account_name,
        authors=list(args.authors),
        affiliation=args.affiliation,
        description=args.description or DESCRIPTIONS[args.policy],
        method_link=args.method_link,
    )
    start = time.perf_counter()
    count = 0
    bar = None
    if sys.stderr.isatty():  # a progress bar for people, never in pipes or CI logs
        from tqdm import tqdm  # only on a terminal

        bar = tqdm(unit="scenario", file=sys.stderr, leave=False, dynamic_ncols=True)

    def counted(rollouts: Iterator[bytes]) -> Iterator[bytes]:
        """The rollouts, counting the simulated scenarios (and moving the bar)."""
        nonlocal count
        for data in rollouts:
            yield data
            count += 1
            if bar is not None:
                bar.update(1)

    try:
        rollouts = simulate_rollouts(
            args.scenarios, args.policy, seed=args.seed, challenge=args.challenge, workers=args.workers
        )
        out = write_submission(counted(rollouts), args.output, metadata, args.shards, args.scenarios)
    except (ParseError, FileNotFoundError, ValueError) as error:
        raise UsageError(str(error)) from None
    finally:
        if bar is not None:
            bar.close()
    report = validate_submission(args.scenarios, out, challenge=args.challenge)
    elapsed = time.perf_counter() - start
    print(f"wrote {out} ({args.policy}, {args.challenge}, {count} scenarios, {elapsed:.1f} s)")
    if not report.ok:
        print(report.format_text(), file=sys.stderr)
        return 1
    print("validation: ok")
    return 0
