"""`wosac-eval validate --scenarios PATH... --submission PATH`: every problem of a submission, before scoring or upload.

Exit codes: 0 the submission is valid (warnings allowed), 1 it is invalid (the
report says why), 2 usage error (bad arguments, missing paths, unreadable
scenario set) or an internal error.
"""

from __future__ import annotations

import argparse
import json
import re
import sys

from wosac_eval.challenges import CHALLENGE_NAMES
from wosac_eval.extras import ENGINES, EngineUnavailableError
from wosac_eval.fronts.usage import UsageError, check_input, scenario_set_hint
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.wire_walks import compile_walks
from wosac_eval.runtime.executors import make_executor
from wosac_eval.validate.validator import ScenarioSetError, load_sim_agents, validate_submission

NAME = "validate"
HELP = "Check a submission (.tar.gz, .tar, folder or .binproto) against a scenario set and report every problem."

_SIZE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([KMGT]i?B?|B)?\s*$", re.IGNORECASE)
_UNITS = {"": 1, "B": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def parse_size(text: str) -> int:
    """'4096', '512M', '40G', '1.5TiB' -> bytes (binary multiples)."""
    match = _SIZE.match(text)
    if not match:
        raise argparse.ArgumentTypeError(f"{text!r} is not a size (e.g. 40G, 512M, 1048576)")
    unit = (match.group(2) or "").upper()[:1]
    value = int(float(match.group(1)) * _UNITS[unit])
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: the size must be positive")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The scenario set, the submission, the challenge, report format and limits."""
    parser.add_argument(
        "--scenarios",
        nargs="+",
        required=True,
        metavar="PATH",
        help="scenario TFRecord files, folders or globs: the scenario set the submission must cover",
    )
    parser.add_argument(
        "--submission",
        required=True,
        metavar="PATH",
        help="the submission: .tar.gz, .tar, a folder of shards or one .binproto",
    )
    parser.add_argument(
        "--challenge",
        choices=CHALLENGE_NAMES,
        default="sim_agents",
        help="the challenge's rules: sim_agents (80 future steps; default) or scenario_gen "
        "(91 steps with box sizes and object types)",
    )
    parser.add_argument("--json", action="store_true", help="print the report as JSON on stdout")
    parser.add_argument(
        "--max-listed",
        type=int,
        default=20,
        metavar="N",
        help="findings shown in full per kind of problem; the rest are counted (default 20)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=1,
        metavar="N",
        help="processes checking shards in parallel (default 1); the report is the same for any N",
    )
    parser.add_argument(
        "--engine",
        choices=ENGINES,
        default="local",
        help="local (this machine, --workers processes; default) or ray (a Ray cluster: one task "
        "per shard; the same report)",
    )
    parser.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="the Ray cluster to join (default $RAY_ADDRESS, else a local Ray is started)",
    )
    parser.add_argument(
        "--max-bytes",
        type=parse_size,
        default=InputLimits.max_total_bytes,
        metavar="SIZE",
        help="refuse a submission that decompresses past SIZE in total (default 64G)",
    )
    parser.add_argument(
        "--max-shard-bytes",
        type=parse_size,
        default=InputLimits.max_member_bytes,
        metavar="SIZE",
        help="refuse a shard that decompresses past SIZE (default 4G)",
    )


def _progress_bar(total: int | None, what: str):
    """A tqdm bar on stderr when stdout is a terminal (never in pipes or CI logs), else None."""
    if not sys.stdout.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=what, unit="scenario", file=sys.stderr, leave=False, dynamic_ncols=True)


def run(args: argparse.Namespace) -> int:
    """Validate and print the report; 0 valid, 1 invalid, 2 usage error."""
    if args.max_listed < 0 or args.workers < 1:
        raise UsageError("--max-listed must be >= 0 and --workers >= 1")
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
