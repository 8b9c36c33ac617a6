"""`wosac-eval score`: the official realism metrics of a submission.

Exit codes: 0 scored, 1 the submission is invalid (the validation report is
printed; `--partial` scores the valid scenarios instead), 2 usage error.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from wosac_eval.extras import BACKENDS, BackendUnavailableError, EngineUnavailableError
from wosac_eval.fronts.usage import (
    UsageError,
    add_challenge,
    add_engine,
    add_input_limits,
    add_scenarios,
    add_workers,
    check_input,
    check_output_file,
    scenario_set_hint,
)
from wosac_eval.metrics.config import PRESET_NAMES
from wosac_eval.options import Backend, MetadataChecks
from wosac_eval.parse.errors import ParseError
from wosac_eval.parse.limits import InputLimits
from wosac_eval.scoring.evaluation import RunOptions, resolve_evaluation
from wosac_eval.scoring.journal import remove_journal
from wosac_eval.scoring.submission import InvalidSubmissionError, score_submission
from wosac_eval.validate import ScenarioSetError

NAME = "score"
HELP = "Score a submission with the official WOSAC realism metrics and write result JSON."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Inputs, challenge and config, output; then where and how to compute (`_add_run_options`)."""
    add_scenarios(parser)
    parser.add_argument(
        "--submission",
        required=True,
        metavar="PATH",
        help="the submission: .tar.gz, .tar, a folder of shards or one .binproto",
    )
    add_challenge(
        parser,
        "sim_agents (80 future steps; default) or scenario_gen (91 steps of every object with box sizes and types)",
    )
    parser.add_argument(
        "--config",
        default=None,
        metavar="PRESET|FILE.textproto",
        help=f"metrics config: a preset ({', '.join(PRESET_NAMES)}) or a "
        "SimAgentMetricsConfig textproto (default: the challenge's current one, "
        "2025 or scenario_gen_2025)",
    )
    parser.add_argument(
        "--output",
        "-o",
        metavar="result.json",
        help="where to write the result JSON (default: stdout); with it, finished scenarios are "
        "kept in result.json.journal while the run lasts, and the same command run again "
        "after an interruption resumes from there",
    )
    parser.add_argument(
        "--restart",
        action="store_true",
        help="with --output: discard the journal of an interrupted run and score everything",
    )
    _add_run_options(parser)


def _add_run_options(parser: argparse.ArgumentParser) -> None:
    """Where and how to compute (workers, engine, backend), what to score and write, and the input limits."""
    add_workers(parser, "score scenarios in N processes of this machine")
    add_engine(parser, "one task per chunk of scenarios")
    parser.add_argument(
        "--partial",
        action="store_true",
        help="score the valid scenarios of an invalid submission; skipped ones are listed",
    )
    parser.add_argument(
        "--strict-metadata",
        action="store_true",
        help="treat metadata gaps (account, method name, flags) as errors, as the challenge "
        "server does (default: warnings, listed on stderr)",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="numpy",
        help="compute features with numpy (default) or with JAX (jit, batched "
        "over scenarios; needs `pip install 'wosac-eval[jax]'`); same results",
    )
    parser.add_argument(
        "--select",
        metavar="top:FRACTION|top:N",
        help="score only the most critical scenarios of the set (the long tail): top:0.1 "
        "the most critical tenth, top:100 the 100 most critical (`wosac-eval criticality` "
        "ranks them); the whole submission is still validated",
    )
    parser.add_argument(
        "--no-analysis",
        action="store_true",
        help="official metrics only: no criticality, driving scores or per-type metrics in the rows",
    )
    parser.add_argument(
        "--per-object",
        nargs="?",
        const="jsonl",
        choices=("jsonl", "parquet"),
        metavar="jsonl|parquet",
        help="with --output R.json: also write every evaluated object's likelihoods, their weights "
        "and its collision / off-road / red-light rollouts to R.objects.jsonl (or, with "
        "parquet, R.objects.parquet, needs pyarrow), streamed as scenarios are scored; "
        'the result\'s "per_object" names the file',
    )

    add_input_limits(parser, InputLimits.max_total_bytes, InputLimits.max_member_bytes)


def _progress() -> Any:
    """A tqdm bar on stderr when it is a terminal: (update callback, bar), or (None, None)."""
    if not sys.stderr.isatty():
        return None, None
    from tqdm import tqdm

    bar = tqdm(unit="scenario", file=sys.stderr, leave=False, dynamic_ncols=True)

    def update(done: int, total: int) -> None:
        """Moves the bar to `done` of `total` scenarios."""
        bar.total = total
        bar.update(done - bar.n)

    return update, bar


def _headline(result: dict) -> str:
    """One line of the leaderboard figures of a result, for stderr."""
    b = result["buckets"]
    return (
        f"scored {result['num_scenarios']} {result['challenge']} scenario(s) with config {result['config']}: "
        f"realism meta-metric {b['realism_meta_metric']:.4f} (kinematic {b['kinematic_metrics']:.4f}, "
        f"interactive {b['interactive_metrics']:.4f}, map-based {b['map_based_metrics']:.4f}), "
        f"minADE {b['min_ade']:.3f} m"
    )


def _stderr_findings(result: dict) -> None:
    """What validation found but scoring went past (metadata gaps, ignored fields), one line per kind."""
    warnings = [g for g in result["validation"]["findings"] if g["severity"] != "error"]
    for group in warnings:
        print(f"warning: {group['code']} ({group['count']}x): {group['first']}", file=sys.stderr)
    if any(g["code"].startswith("metadata.") for g in warnings):
        print(
            "warning: metadata gaps do not stop local scoring, but the challenge server refuses them "
            "(`wosac-eval validate` or --strict-metadata apply its rules)",
            file=sys.stderr,
        )


def _stderr_coverage(result: dict) -> None:
    """Scored of expected scenarios, and why the others were skipped (partial scoring)."""
    coverage = result["coverage"]
    if "selection" in result:
        chosen = result["selection"]
        print(
            f"selection {chosen['rule']}: the {chosen['scenarios']} most critical of {chosen['of']} scenario(s) "
            f"(criticality >= {chosen['min_criticality']:.3f})",
            file=sys.stderr,
        )
    if result["skipped"]:
        print(
            f"partial result: scored {coverage['scored']} of {coverage['expected']} scenario(s) "
            f'({coverage["fraction"]:.1%}); {len(result["skipped"])} skipped (listed under "skipped"), '
            f"e.g. {result['skipped'][0]['scenario_id']}: {result['skipped'][0]['reason']}",
            file=sys.stderr,
        )


def _journal(args: argparse.Namespace) -> Path | None:
    """The run's journal beside --output (None without it), said when an earlier run left one."""
    if not args.output:
        if args.restart:
            raise UsageError("--restart needs --output (the journal lives beside the result)")
        return None
    journal = Path(args.output).with_name(Path(args.output).name + ".journal")
    if journal.exists():
        if args.restart:
            remove_journal(journal)
        else:
            print(
                f"resuming from {journal}: scenarios an earlier run finished are not scored again "
                "(--restart scores everything)",
                file=sys.stderr,
            )
    return journal


def _objects(args: argparse.Namespace) -> Path | None:
    """The per-object file beside --output (None without --per-object), checked before any work."""
    if args.per_object is None:
        return None
    if not args.output:
        raise UsageError("--per-object needs --output (the objects are written beside the result)")
    from wosac_eval.scoring.objects import objects_path_for

    path = objects_path_for(args.output, args.per_object)
    if args.per_object == "parquet":
        try:
            import pyarrow.parquet  # noqa: F401
        except ImportError:
            raise UsageError("--per-object parquet needs pyarrow (pip install pyarrow); jsonl needs nothing") from None
    check_output_file(str(path), "--per-object")
    return path


def write_result(result: dict, path: Path) -> None:
    """The result document, streamed to a temporary file beside `path` and renamed over it: a reader
    never sees half a document, and a 44,097-scenario result is never one string in memory."""
    temp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(temp, "w") as f:
            json.dump(result, f, indent=1)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(temp, path)
    finally:
        temp.unlink(missing_ok=True)


def run_options(args: argparse.Namespace, objects: Path | None = None) -> RunOptions:
    """The run's options as the command line gives them (checked by `RunOptions`); `objects`: the
    per-object file of --per-object (`_objects`)."""
    return RunOptions(
        backend=args.backend,
        engine=args.engine,
        ray_address=args.ray_address,
        workers=args.workers,
        allow_partial=args.partial,
        metadata_checks=MetadataChecks.ERROR if args.strict_metadata else MetadataChecks.WARN,
        select=args.select,
        analysis=not args.no_analysis,
        limits=InputLimits(max_member_bytes=args.max_shard_bytes, max_total_bytes=args.max_bytes),
        per_object=objects is not None,
        objects=objects,
    )


def run(args: argparse.Namespace) -> int:
    """Validate and score the submission, write the result; 0 scored, 1 invalid submission, 2 usage error."""
    check_output_file(args.output, "--output")
    check_input(args.submission, "--submission", "submission")
    objects = _objects(args)
    try:  # everything asked is checked here, once, before any long work
        evaluation = resolve_evaluation(args.challenge, args.config, run_options(args, objects))
    except (BackendUnavailableError, EngineUnavailableError, ValueError) as error:
        raise UsageError(str(error)) from None
    if evaluation.options.backend is Backend.JAX:
        # This process is the CLI's own: features bit-identical to numpy on CPU (no fused multiply-adds),
        # and XLA's compiled programs kept between runs (JAX's persistent compilation cache).
        from wosac_eval.backends.jax_backend import exact_cpu
        from wosac_eval.backends.program_cache import keep_compiled_programs

        keep_compiled_programs()  # before the first compilation (exact_cpu's probe), when JAX reads it
        exact_cpu()
    journal = _journal(args)
    update, bar = _progress()
    try:
        result = score_submission(
            args.scenarios,
            args.submission,
            progress=update,
            evaluation=evaluation,
            journal=journal,
        )
    except InvalidSubmissionError as error:
        print(error.report.format_text(), file=sys.stderr)
        if error.metadata:
            print(
                "wosac-eval score: the submission's metadata has errors (listed above); fix them: partial "
                "scoring skips invalid scenarios, never the metadata",
                file=sys.stderr,
            )
        else:
            print(
                "wosac-eval score: the submission is invalid; fix it, or pass --partial to score its valid scenarios",
                file=sys.stderr,
            )
        return 1
    except (ScenarioSetError, ParseError) as error:
        raise UsageError(f"{error}{scenario_set_hint(args.scenarios, args.submission)}") from None
    except (FileNotFoundError, ValueError, EngineUnavailableError) as error:
        raise UsageError(str(error)) from None
    except KeyboardInterrupt:
        if journal is not None and journal.exists():
            print(
                f"\nwosac-eval score: the scenarios finished so far are kept in {journal}; run the same "
                "command again to resume",
                file=sys.stderr,
            )
        raise
    finally:
        if bar is not None:
            bar.close()
    _stderr_findings(result)
    if args.output:
        write_result(result, Path(args.output))
        if journal is not None:  # always, with --output
            remove_journal(journal)  # the result is on disk: nothing left to resume
        print(_headline(result), file=sys.stderr)
        print(f"results written to {args.output}", file=sys.stderr)
        if objects is not None:
            print(f"{result['per_object']['num_objects']} object(s) written to {objects}", file=sys.stderr)
    else:
        print(json.dumps(result, indent=1))
    _stderr_coverage(result)
    return 0
