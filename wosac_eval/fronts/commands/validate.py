"""`wosac-eval validate --scenarios PATH... --submission PATH`: every problem of a submission, before scoring or upload.

Exit codes: 0 the submission is valid (warnings allowed), 1 it is invalid (the
report says why), 2 usage error (bad arguments, missing paths, unreadable
scenario set) or an internal error.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from wosac_eval.extras import EngineUnavailableError
from wosac_eval.fronts.usage import (
    UsageError,
    add_challenge,
    add_engine,
    add_input_limits,
    add_scenarios,
    add_workers,
    check_input,
    scenario_set_hint,
)
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.wire_walks import compile_walks
from wosac_eval.runtime.executors import make_executor
from wosac_eval.validate import ScenarioSetError, load_sim_agents, validate_submission

NAME = "validate"
HELP = "Check a submission (.tar.gz, .tar, folder or .binproto) against a scenario set and report every problem."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The scenario set, the submission, the challenge, report format and limits."""
    add_scenarios(parser, "the scenario set the submission must cover")
    parser.add_argument(
        "--submission",
        required=True,
        metavar="PATH",
        help="the submission: .tar.gz, .tar, a folder of shards or one .binproto",
    )
    add_challenge(
        parser,
        "the challenge's rules: sim_agents (80 future steps; default) or scenario_gen (91 steps with box sizes "
        "and object types)",
    )
    parser.add_argument("--json", action="store_true", help="print the report as JSON on stdout")
    parser.add_argument(
        "--max-listed",
        type=int,
        default=20,
        metavar="N",
        help="findings shown in full per kind of problem; the rest are counted (default 20)",
    )
    add_workers(parser, "processes checking shards in parallel")
    add_engine(parser, "one task per shard")
    add_input_limits(parser, InputLimits.max_total_bytes, InputLimits.max_member_bytes)


def _progress_bar(total: int | None, what: str) -> Any:
    """A tqdm bar on stderr when stdout is a terminal (never in pipes or CI logs), else None."""
    if not sys.stdout.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=what, unit="scenario", file=sys.stderr, leave=False, dynamic_ncols=True)


def run(args: argparse.Namespace) -> int:
    """Validate and print the report; 0 valid, 1 invalid, 2 usage error."""
    if args.max_listed < 0:
        raise UsageError("--max-listed must be >= 0")
    check_input(args.submission, "--submission", "submission")
    limits = InputLimits(max_member_bytes=args.max_shard_bytes, max_total_bytes=args.max_bytes)
    bar = None
    try:
        executor = make_executor(
            args.engine, workers=args.workers, ray_address=args.ray_address, warm_up=compile_walks
        )  # numba's wire walks compiled once here, not in each worker of a fresh installation
        bar = _progress_bar(None, "reading scenarios")
        agents = load_sim_agents(args.scenarios, progress=bar.update if bar is not None else None)
        if bar is not None:
            bar.close()
        bar = _progress_bar(len(agents), "validating")
        report = validate_submission(
            args.scenarios,
            args.submission,
            max_listed=args.max_listed,
            limits=limits,
            progress=bar.update if bar is not None else None,
            sim_agents=agents,
            workers=args.workers,
            challenge=args.challenge,
            executor=executor,
        )
    except ScenarioSetError as error:
        raise UsageError(f"{error}{scenario_set_hint(args.scenarios, args.submission)}") from None
    except (OSError, EngineUnavailableError) as error:  # missing / unreadable paths, I/O errors
        raise UsageError(str(error)) from None
    finally:
        if bar is not None:
            bar.close()
    if hasattr(sys.stdout, "reconfigure"):  # names from the submission must not crash a non-UTF-8 console
        sys.stdout.reconfigure(errors="backslashreplace")
    if args.json:
        json.dump(report.to_dict(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(report.format_text())
    return 0 if report.ok else 1
