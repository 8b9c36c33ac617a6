"""`wosac-eval report RESULT.json --html report.html`: a self-contained HTML report of a scoring run.

Exit codes: 0 report written, 2 a result could not be read or compared, or the
output could not be written.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from wosac_eval.fronts.usage import UsageError, add_scenarios, check_input, check_output_file
from wosac_eval.results.compare import compare_results
from wosac_eval.results.report import render_report, worst_scenarios
from wosac_eval.results.stats import PairedSettings
from wosac_eval.scoring.result_reader import ResultError, load_result

NAME = "report"
HELP = (
    "Write a self-contained HTML report (scores, buckets, rates, distributions, worst scenarios) of a `score` result."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The result, the HTML output, an optional baseline to compare with, and report settings."""
    parser.add_argument("result", metavar="RESULT.json", help="result of `wosac-eval score --output`")
    parser.add_argument("--html", required=True, metavar="PATH", help="where to write the report")
    parser.add_argument("--compare", metavar="BASE.json", help="add a paired comparison against this baseline result")
    parser.add_argument(
        "--top", type=int, default=10, metavar="K", help="worst scenarios listed per metric (default 10)"
    )
    parser.add_argument("--title", help="page title (default: from the result's file name)")
    add_scenarios(parser, "with --submission, the scenario set, to draw the worst scenes", required=False)
    parser.add_argument(
        "--submission", metavar="PATH", help="with --scenarios: the scored submission, to draw the worst scenes"
    )
    parser.add_argument(
        "--scenes",
        type=int,
        default=3,
        metavar="N",
        help="worst scenes drawn when --scenarios and --submission are given (default 3)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the comparison's bootstrap / permutation draws")
    parser.add_argument("--n-boot", type=int, default=5000, help="bootstrap resamples of the comparison (default 5000)")
    parser.add_argument("--n-perm", type=int, default=5000, help="sign flips of the comparison (default 5000)")


def run(args: argparse.Namespace) -> int:
    """Render the report; checks the output folder before any work."""
    if args.top < 1:
        raise UsageError("--top must be at least 1")
    check_output_file(args.html, "--html")  # checked first: rendering takes seconds on a large result
    if (args.scenarios is None) != (args.submission is None):
        raise UsageError("--scenarios and --submission go together (they draw the worst scenes)")
    if args.submission is not None:
        check_input(args.submission, "--submission", "submission")
    if args.scenes < 0:
        raise UsageError("--scenes must be >= 0")
    try:
        result = load_result(args.result)
        base = comparison = None
        if args.compare:
            base = load_result(args.compare)
            settings = PairedSettings(seed=args.seed, n_boot=args.n_boot, n_perm=args.n_perm)
            comparison = compare_results(base, result, settings=settings)
    except (ResultError, ValueError) as e:  # CompareError is a ValueError, as a bad setting's error
        raise UsageError(str(e)) from None
    scenes = []
    if args.submission is not None and args.scenes:
        from wosac_eval.parse.errors import ParseError
        from wosac_eval.results.scene_plot import scene_pictures

        try:
            scenes = scene_pictures(
                args.scenarios, args.submission, worst_scenarios(result, args.scenes), result.challenge
            )
        except (ParseError, ValueError) as e:
            raise UsageError(f"cannot draw the worst scenes: {e}") from None
    page = render_report(result, base=base, comparison=comparison, top_k=args.top, title=args.title, scenes=scenes)
    try:
        Path(args.html).write_text(page, encoding="utf-8")
    except OSError as e:
        raise UsageError(f"cannot write {args.html}: {e.strerror}") from None
    print(f"wrote {args.html} ({len(page) // 1024} KiB)")
    return 0
