"""`wosac-eval compare BASE.json NEW.json`: paired comparison of two scoring runs, and a CI gate.

Exit codes: 0 compared (and every gate passed), 1 a gate failed, 2 the results
could not be compared (unreadable file, unknown metric, bad gate, no shared scenario).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from wosac_eval.arrays.object_types import ANALYSED_TYPES
from wosac_eval.fronts.usage import UsageError, check_output_file
from wosac_eval.results.compare import ALIASES, METRICS, CompareError, Gate, canonical_metric, compare_results
from wosac_eval.results.compare_text import format_markdown, format_table
from wosac_eval.results.stats import PairedSettings
from wosac_eval.results.stratify import STRATIFY, StratifyError, format_strata, stratified_comparison
from wosac_eval.scoring.result_reader import ResultError, ScoringResult, load_result

NAME = "compare"
HELP = (
    "Compare two `score` results scenario by scenario (paired bootstrap CI, permutation p-value); gate on regressions."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The two results, the metrics to report, the gates, and the statistics settings."""
    parser.add_argument("base", metavar="BASE.json", help="result of the reference run (`wosac-eval score --output`)")
    parser.add_argument("new", metavar="NEW.json", help="result of the run under test")
    parser.add_argument(
        "--metric",
        action="append",
        metavar="NAME",
        help="report only this metric (repeatable or comma-separated; default all): "
        + ", ".join(METRICS)
        + "; aliases: "
        + ", ".join(f"{a}={m}" for a, m in ALIASES.items()),
    )
    parser.add_argument(
        "--fail-if-worse",
        action="append",
        default=[],
        metavar="METRIC:DELTA",
        help="exit 1 when NEW is worse than BASE on METRIC by more than DELTA (in the metric's "
        "units, or with %% a share of the baseline value; mean over shared scenarios; "
        "repeatable), e.g. metametric:0.005 or metametric:1%%",
    )
    parser.add_argument(
        "--only-significant",
        action="store_true",
        help="a gate fails only when the regression is also statistically significant",
    )
    parser.add_argument("--alpha", type=float, default=0.05, help="significance level (default 0.05: 95%% CIs)")
    parser.add_argument(
        "--adjust",
        choices=("none", "holm"),
        default="none",
        help="base verdicts on Holm-adjusted p-values (family-wise error control over the metrics)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the bootstrap and permutation draws (default 0)")
    parser.add_argument("--n-boot", type=int, default=5000, help="bootstrap resamples (default 5000)")
    parser.add_argument(
        "--n-perm", type=int, default=5000, help="random sign flips of the permutation test (default 5000)"
    )
    parser.add_argument(
        "--min-shared",
        type=int,
        default=1,
        metavar="N",
        help="error (exit 2) when the results share fewer than N scenarios (default 1)",
    )
    parser.add_argument(
        "--stratify",
        choices=STRATIFY,
        help="also compare per stratum: criticality terciles and the long tail (top decile) vs "
        f"the rest, or per object type ({', '.join(ANALYSED_TYPES)}); paired CI, p-value, "
        "Holm-adjusted p and Cohen's d per stratum, for the --metric metrics (default "
        "metametric)",
    )
    parser.add_argument(
        "--per-object",
        action="store_true",
        help="also compare object by object (both results scored with `score --per-object`): "
        "the objects, matched by scenario_id and object_id, and the object type x criticality "
        "strata whose likelihoods changed most, with paired CIs over scenes, for the --metric "
        "likelihoods (default: the objects' meta-metric and every likelihood)",
    )
    parser.add_argument(
        "--top",
        type=int,
        default=10,
        metavar="K",
        help="with --per-object: objects listed each way and strata listed (default 10)",
    )
    parser.add_argument("--json", action="store_true", help="print the comparison as JSON on stdout")
    parser.add_argument(
        "--json-output",
        metavar="PATH",
        help="also write the comparison as JSON to PATH (the table still goes to stdout)",
    )
    parser.add_argument(
        "--markdown-output",
        metavar="PATH",
        help="also write the comparison as a Markdown table to PATH (for a CI job summary)",
    )


def _metrics_named(args: argparse.Namespace) -> list[str]:
    """The --metric names (repeated or comma-separated), canonical; none without the option."""
    return [canonical_metric(m.strip()) for spec in args.metric or [] for m in spec.split(",") if m.strip()]


def _per_object(args: argparse.Namespace, base: ScoringResult, new: ScoringResult, settings: PairedSettings) -> Any:
    """The object-by-object comparison (with --per-object; None without it)."""
    if not args.per_object:
        return None
    if args.top < 1:
        raise UsageError("--top must be at least 1")
    # Here, not at the top: the per-object tables need the features' modules (a second), which a plain
    # `compare` of two result files never loads.
    from wosac_eval.results.per_object_compare import compare_objects

    return compare_objects(base, new, metrics=_metrics_named(args) or None, top=args.top, settings=settings)


def _objects_markdown(objects: Any) -> str:
    if objects is None:
        return ""
    from wosac_eval.results.per_object_compare import format_objects_markdown  # loaded with compare_objects

    return "\n" + format_objects_markdown(objects)


def _write(path: str, text: str) -> None:
    try:
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
    except OSError as e:
        raise UsageError(f"cannot write {path}: {e.strerror}") from None


def run(args: argparse.Namespace) -> int:
    """Compare, print (table, JSON, Markdown) and apply the gates; 0 passed, 1 a gate failed, 2 not comparable."""
    check_output_file(args.json_output, "--json-output")
    check_output_file(args.markdown_output, "--markdown-output")
    try:
        settings = PairedSettings(
            alpha=args.alpha, adjust=args.adjust, seed=args.seed, n_boot=args.n_boot, n_perm=args.n_perm
        )
        gates = [Gate.parse(g) for g in args.fail_if_worse]
        base = load_result(args.base)
        new = load_result(args.new)
        comparison = compare_results(
            base, new, args.metric, gates, settings, min_shared=args.min_shared, only_significant=args.only_significant
        )
        strata = None
        if args.stratify:
            strata = stratified_comparison(base, new, args.stratify, _metrics_named(args) or ["metametric"], settings)
        objects = _per_object(args, base, new, settings)
    except (ResultError, CompareError, StratifyError, ValueError) as e:
        raise UsageError(str(e)) from None
    document = {
        **comparison.to_json(),
        **({"stratified": strata.to_json()} if strata else {}),
        **({"per_object": objects.to_json()} if objects else {}),
    }
    if args.json_output:
        _write(args.json_output, json.dumps(document, indent=2) + "\n")
    if args.markdown_output:
        _write(args.markdown_output, format_markdown(comparison) + _objects_markdown(objects))
    if args.json:
        for w in comparison.warnings:  # also on stderr, where CI logs show them next to the JSON
            print(f"wosac-eval compare: warning: {w}", file=sys.stderr)
        json.dump(document, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(format_table(comparison))
        if strata:
            print()
            print(format_strata(strata))
        if objects:
            from wosac_eval.results.per_object_compare import format_objects  # loaded with compare_objects

            print()
            print(format_objects(objects))
    return 0 if comparison.passed else 1
