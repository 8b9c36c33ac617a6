"""`wosac-eval criticality`: how demanding each scenario of a set is, from its log alone (no submission).

Exit codes: 0 written, 2 usage error (missing scenarios, unwritable output, an
unknown format, pyarrow missing for .parquet, a Ray engine that cannot start or connect).
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

from wosac_eval.analysis.criticality_scores import COMPONENTS
from wosac_eval.fronts.usage import UsageError, add_engine, add_scenarios, add_workers, check_output_file

NAME = "criticality"
HELP = (
    "Rate every scenario of a set for criticality (kinematic volatility, interaction, map events, "
    "behaviour rarity) from the log alone, most critical first; for curating long-tail sets."
)
FORMATS = (".csv", ".parquet", ".json")
SHOWN = 10


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_scenarios(parser)
    parser.add_argument(
        "--output",
        "-o",
        metavar="FILE.csv|.parquet|.json",
        help="the table, one row per scenario, most critical first (.parquet needs pyarrow); "
        f"without it the {SHOWN} most critical are printed",
    )
    parser.add_argument(
        "--per-step", action="store_true", help="add each scenario's per-step criticality (columns step_0 .. step_90)"
    )
    add_workers(parser, "processes rating scenarios")
    add_engine(parser, "one task per batch of scenarios")


def table_rows(result: dict) -> list[dict]:
    """Flat rows: rank, scenario_id, score, long_tail, peak_step, each component, each raw value[, steps]."""
    rows = []
    for scene in result["scenarios"]:
        row = {
            "rank": scene["rank"],
            "scenario_id": scene["scenario_id"],
            "score": scene["score"],
            "long_tail": scene["long_tail"],
            "peak_step": scene["peak_step"],
        }
        row.update({name: scene["components"][name] for name in COMPONENTS})
        row.update({f"raw_{name}": scene["raw"][name] for name in COMPONENTS})
        for step, value in enumerate(scene.get("steps", ())):
            row[f"step_{step}"] = value
        rows.append(row)
    return rows


def write_table(rows: list[dict], path: Path) -> None:
    suffix = path.suffix.lower()
    if suffix == ".json":
        path.write_text(json.dumps(rows, indent=1) + "\n")
    elif suffix == ".csv":
        with path.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]) if rows else ["rank", "scenario_id"])
            writer.writeheader()
            writer.writerows(rows)
    else:
        import pyarrow
        import pyarrow.parquet

        pyarrow.parquet.write_table(pyarrow.Table.from_pylist(rows), path)


def run(args: argparse.Namespace) -> int:
    from wosac_eval.analysis.scenario_set_criticality import scenario_set_criticality
    from wosac_eval.extras import EngineUnavailableError
    from wosac_eval.parse.errors import ParseError

    if args.output is not None:
        if Path(args.output).suffix.lower() not in FORMATS:
            raise UsageError(f"--output {args.output}: the suffix chooses the format: {', '.join(FORMATS)}")
        check_output_file(args.output, "--output")
        if Path(args.output).suffix.lower() == ".parquet":
            try:
                import pyarrow.parquet  # noqa: F401
            except ImportError:
                raise UsageError(
                    "--output .parquet needs pyarrow (pip install pyarrow); .csv and .json need nothing"
                ) from None
    try:
        result = scenario_set_criticality(
            args.scenarios,
            workers=args.workers,
            engine=args.engine,
            ray_address=args.ray_address,
            per_step=args.per_step,
        )
    except (ParseError, FileNotFoundError, EngineUnavailableError) as error:
        raise UsageError(str(error)) from None
    rows = table_rows(result)
    if args.output is not None:
        try:
            write_table(rows, Path(args.output))
        except OSError as error:
            raise UsageError(f"--output {args.output}: cannot write: {error.strerror or error}") from None
    print(
        f"{result['num_scenarios']} scenario(s); long tail (top decile): score >= {result['long_tail_threshold']:.3f}"
    )
    for row in rows[: SHOWN if args.output is None else 3]:
        print(f"{row['rank']:>4}  {row['score']:.3f}  {row['scenario_id']}  peak step {row['peak_step']}")
    if args.output is not None:
        print(f"wrote {args.output}")
    return 0
