"""`wosac-eval submit`: send a submission to a wosac-server (server/), resumably; with --wait, follow it.

Exit codes: 0 uploaded (with --wait: scored), 1 the server refused it (its reason is printed), the
job failed (its error is printed), or the upload could not go on (the file changed meanwhile, another
run is uploading it), 2 usage error, or the server unreachable or failing past the retries (run the
same command again: the upload goes on where the server holds it), 130 interrupted (the same: run
it again to resume).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import TYPE_CHECKING

from wosac_eval.client import (
    DEFAULT_CHUNK_BYTES,
    KEY_ENV,
    ArgumentError,
    ProtocolError,
    ServerUnavailable,
    SubmissionFailed,
    SubmitError,
    SubmitOptions,
    submit,
)
from wosac_eval.fronts.usage import UsageError, add_challenge, check_output_file, size_in_bytes

if TYPE_CHECKING:
    from tqdm import tqdm

NAME = "submit"
HELP = "Upload a submission to a wosac-eval scoring service (resumable); with --wait, print its result."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = (
        f"The key defaults to ${KEY_ENV}, so it need not appear in the shell's history. An "
        "interrupted upload (Ctrl-C, a dropped network, a server restart) goes on where the "
        "server holds it when the same command runs again; once uploaded, running it again "
        "follows the same submission (--new sends the file again)."
    )
    parser.add_argument(
        "submission",
        metavar="SUBMISSION",
        help="the submission file: .tar.gz, .tar.bz2, .tar.xz, .tar, or one .binproto[.gz|.bz2|.xz]",
    )
    parser.add_argument("--server", required=True, metavar="URL", help="the service, e.g. https://wosac.example.org")
    parser.add_argument(
        "--key",
        default=None,
        metavar="KEY",
        help=f"the API key (wosac_...; default: ${KEY_ENV}, which keeps it out of the shell's history)",
    )
    parser.add_argument("--method", required=True, metavar="NAME", help="the leaderboard name of the method")
    add_challenge(parser, "sim_agents (default) or scenario_gen")
    parser.add_argument(
        "--config",
        default=None,
        metavar="NAME",
        help="the metrics config the server scores with (default: the challenge's current one, "
        "2025 or scenario_gen_2025)",
    )
    parser.add_argument("--publish", action="store_true", help="show the result on the public leaderboard")
    parser.add_argument(
        "--partial",
        action="store_true",
        help="score the valid scenarios of a submission that does not cover the whole scenario set",
    )
    parser.add_argument(
        "--wait", action="store_true", help="follow the job (state and progress on stderr) and print its result row"
    )
    parser.add_argument(
        "--output",
        "-o",
        metavar="result.json",
        help="with --wait: write the result document (the JSON of `wosac-eval score`) there",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print the submission's status as JSON on stdout (with --wait: the final one, "
        'with "result") instead of the text row',
    )
    parser.add_argument(
        "--new",
        action="store_true",
        help="forget an earlier upload of this file (an unfinished one is deleted) and send it again",
    )
    parser.add_argument(
        "--chunk-bytes",
        type=size_in_bytes,
        default=DEFAULT_CHUNK_BYTES,
        metavar="SIZE",
        help="bytes per upload request (default 64M; K, M, G accepted)",
    )
    parser.add_argument(
        "--limit-rate",
        type=size_in_bytes,
        default=None,
        metavar="SIZE",
        help="send at most SIZE bytes per second (e.g. 10M)",
    )
    parser.add_argument(
        "--state-dir",
        default=None,
        metavar="DIR",
        help="where unfinished uploads are remembered (default $XDG_CACHE_HOME/wosac-eval/uploads, "
        "else ~/.cache/wosac-eval/uploads); the key is never written there",
    )


class _Reporter:
    """Progress and events on stderr: tqdm bars on a terminal, else a line per tenth done."""

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()
        self.bars: dict[str, tqdm] = {}
        self.tenths: dict[str, int] = {}

    def log(self, message: str) -> None:
        if self.bars:
            from tqdm import tqdm

            tqdm.write(message, file=sys.stderr)
        else:
            print(message, file=sys.stderr, flush=True)

    def progress(self, stage: str, done: int, total: int | None) -> None:
        if self.tty:
            bar = self.bars.get(stage)
            if bar is None:
                from tqdm import tqdm

                options = (
                    {"unit": "B", "unit_scale": True, "unit_divisor": 1024}
                    if stage == "upload"
                    else {"unit": "scenario"}
                )
                bar = self.bars[stage] = tqdm(
                    desc=stage, total=total, file=sys.stderr, leave=False, dynamic_ncols=True, **options
                )
            bar.total = total
            bar.n = done
            bar.refresh()
            if total and done >= total:  # this stage is over: its bar goes (a step back makes a new one)
                bar.close()
                del self.bars[stage]
            return
        if not total:
            return
        tenth = done * 10 // total
        if tenth != self.tenths.setdefault(stage, tenth):  # from the second report on: its start is said
            self.tenths[stage] = tenth
            unit = "bytes" if stage == "upload" else "scenarios"
            verb = "uploaded" if stage == "upload" else "scored"
            print(f"{verb} {done / total:.0%} ({done:,} of {total:,} {unit})", file=sys.stderr, flush=True)

    def close(self) -> None:
        for bar in self.bars.values():
            bar.close()
        self.bars.clear()


def result_row(status: dict) -> str:
    """The result's leaderboard figures: a header line and one row."""
    result = status["result"]
    b = result["buckets"]
    cells = [
        ("submission", status["id"]),
        ("method", status["method"]),
        ("challenge", result["challenge"]),
        ("config", result["config"]),
        ("scenarios", str(result["num_scenarios"])),
        ("meta-metric", f"{b['realism_meta_metric']:.4f}"),
        ("kinematic", f"{b['kinematic_metrics']:.4f}"),
        ("interactive", f"{b['interactive_metrics']:.4f}"),
        ("map-based", f"{b['map_based_metrics']:.4f}"),
        ("minADE", f"{b['min_ade']:.3f}"),
    ]
    if status.get("partial"):
        cells.append(("coverage", f"{status['coverage']:.1%}"))
    widths = [max(len(a), len(b)) for a, b in cells]
    return (
        "  ".join(a.ljust(w) for (a, _), w in zip(cells, widths)).rstrip()
        + "\n"
        + "  ".join(b.ljust(w) for (_, b), w in zip(cells, widths)).rstrip()
    )


def run(args: argparse.Namespace) -> int:
    """Upload (or resume, or find) the submission; 0 done, 1 refused or failed, 2 usage or unreachable."""
    if args.output and not args.wait:
        raise UsageError("--output needs --wait (the result exists once the job is done)")
    check_output_file(args.output, "--output")
    key = args.key if args.key is not None else os.environ.get(KEY_ENV)
    if not key:
        raise UsageError(f"no API key: pass --key, or set {KEY_ENV} (which keeps it out of the shell's history)")
    reporter = _Reporter()
    try:
        options = SubmitOptions(
            server=args.server,
            key=key,
            method=args.method,
            challenge=args.challenge,
            config=args.config,
            publish=args.publish,
            allow_partial=args.partial,
            output=args.output,
            chunk_bytes=args.chunk_bytes,
            limit_rate=args.limit_rate,
            progress=reporter.progress,
            log=reporter.log,
            state_dir=args.state_dir,
        )
        status = submit(args.submission, options, wait=args.wait, new=args.new)
    except ArgumentError as error:
        raise UsageError(str(error)) from None
    except SubmissionFailed as failed:
        reporter.close()
        if args.json:
            print(json.dumps(failed.status, indent=1))
        print(f"wosac-eval submit: {failed}", file=sys.stderr)
        return 1
    except (ServerUnavailable, ProtocolError) as error:
        reporter.close()
        print(f"wosac-eval submit: {error}", file=sys.stderr)
        return 2
    except SubmitError as error:
        reporter.close()
        print(f"wosac-eval submit: {error}", file=sys.stderr)
        return 1
    finally:
        reporter.close()
    if args.json:
        print(json.dumps(status, indent=1))
    elif "result" in status:
        print(result_row(status))
    else:
        print(f"submission {status['id']}: {status['state']}")
    if "result" in status:
        if args.output:
            print(f"result written to {args.output}", file=sys.stderr)
    elif not args.wait:
        where = f"{args.server.rstrip('/')}/v1/submissions/{status['id']}"
        print(f"follow it: the same command with --wait, or GET {where}", file=sys.stderr)
    return 0
