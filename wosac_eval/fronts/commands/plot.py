"""`wosac-eval plot`: a picture of one scenario, its log and the submitted rollouts, with the metric events.

Exit codes: 0 written, 1 the scenario's rollouts are invalid (the findings are
printed), 2 usage error (missing scenario, unknown format, unwritable output).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from wosac_eval.fronts.usage import UsageError, add_challenge, add_scenarios, check_input, check_output_file

NAME = "plot"
HELP = (
    "Draw a scenario (map, log, rollouts, boxes at a step, collisions / off-road / red-light runs) "
    "as .png, .gif or .html."
)


def _rollout_list(text: str) -> list[int] | None:
    if text == "all":
        return None
    try:
        return [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give rollout indices such as 0,1,2 (or all)") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The scenario set and scenario, the submission, the output and what to show."""
    add_scenarios(parser)
    parser.add_argument(
        "--scenario", metavar="ID", help="the scenario to draw (default: the only one of the scenario set)"
    )
    parser.add_argument(
        "--submission", metavar="PATH", help="the submission whose rollouts to draw (default: the log alone)"
    )
    add_challenge(parser, "the submission's challenge (default sim_agents)")
    parser.add_argument(
        "--output",
        "-o",
        required=True,
        metavar="FILE.png|.gif|.html",
        help="the picture; its suffix chooses: .png (one step), .gif (the scene playing), "
        ".html (a page with a step slider and the list of events)",
    )
    parser.add_argument(
        "--step",
        type=int,
        metavar="N",
        help="the logged step (0..90, 10 is the current one) whose boxes a .png shows "
        "(default: the last event, else the last step)",
    )
    parser.add_argument(
        "--rollouts",
        type=_rollout_list,
        default=[0, 1, 2],
        metavar="I,J,...|all",
        help="rollouts drawn as lines (default 0,1,2; all: every rollout)",
    )
    parser.add_argument(
        "--density", action="store_true", help="draw the positions of all rollouts as a density instead of lines"
    )
    parser.add_argument(
        "--every", type=int, default=2, metavar="K", help="a .gif or .html frame every K steps (default 2)"
    )
    parser.add_argument(
        "--object",
        type=int,
        metavar="ID",
        help="with --submission, a .png of one evaluated object: its rollouts against its log on "
        "the map, and its speed, acceleration, distance to the nearest object and to the road "
        "edge over the steps, each rollout and their median against the log's",
    )


def _pick_scenario(index: Any, wanted: str | None) -> str:
    ids = list(index)
    if wanted is not None:
        if wanted not in index:
            shown = ", ".join(ids[:5]) + (", ..." if len(ids) > 5 else "")
            raise UsageError(f"--scenario {wanted}: not in the scenario set ({len(ids)} scenarios: {shown})")
        return wanted
    if len(ids) != 1:
        raise UsageError(
            f"the scenario set holds {len(ids)} scenarios: choose one with --scenario (e.g. {', '.join(ids[:3])})"
        )
    return ids[0]


def run(args: argparse.Namespace) -> int:
    """Find the scenario and its rollouts, check them, draw; 0 written, 1 invalid rollouts, 2 usage error."""
    from wosac_eval.parse.errors import ParseError
    from wosac_eval.parse.scenarios import ScenarioIndex
    from wosac_eval.parse.submission_source import find_scenario_rollouts
    from wosac_eval.results.scene_plot import FORMATS, scene_view, write_scene
    from wosac_eval.validate import rules

    if Path(args.output).suffix.lower() not in FORMATS:
        raise UsageError(f"--output {args.output}: the suffix chooses the format: {', '.join(FORMATS)}")
    if args.object is not None:
        if args.submission is None:
            raise UsageError("--object needs --submission (it draws the object's rollouts)")
        if Path(args.output).suffix.lower() != ".png":
            raise UsageError(f"--object draws a .png, not {args.output}")
    check_output_file(args.output, "--output")
    if args.step is not None and not 0 <= args.step <= 90:
        raise UsageError(f"--step {args.step}: steps run from 0 to 90 (10 is the current one)")
    if args.every < 1:
        raise UsageError("--every must be >= 1")
    if args.submission is not None:
        check_input(args.submission, "--submission", "submission")
    try:
        index = ScenarioIndex(args.scenarios)
        scenario_id = _pick_scenario(index, args.scenario)
        scenario = index.load(scenario_id)
        rollouts = None
        if args.submission is not None:
            rollouts = find_scenario_rollouts(args.submission, [scenario_id]).get(scenario_id)
            if rollouts is None:
                raise UsageError(f"--submission {args.submission}: holds no rollouts of scenario {scenario_id}")
    except (ParseError, ValueError) as error:
        if isinstance(error, UsageError):
            raise
        raise UsageError(str(error)) from None
    if rollouts is not None:
        errors = [
            f
            for f in rules.check_scenario_rollouts(rollouts, rules.sim_agent_ids(scenario), challenge=args.challenge)
            if f.severity == "error"
        ]
        if errors:
            for finding in errors[:5]:
                print(f"  - {finding.message}", file=sys.stderr)
            hints: dict[str, int] = {}
            for finding in errors:
                if finding.hint is not None:
                    hints[finding.hint] = hints.get(finding.hint, 0) + 1
            for hint, count in hints.items():  # once per cause, not on every line
                print(f"  hint ({count} of {len(errors)}): {hint}", file=sys.stderr)
            print(
                f"wosac-eval plot: scenario {scenario_id}: {len(errors)} problem(s) in the rollouts "
                f"(`wosac-eval validate` reports them all)",
                file=sys.stderr,
            )
            return 1
    if args.object is not None:
        from wosac_eval.results.object_plot import object_png

        assert rollouts is not None  # --object needs --submission, whose rollouts were found (both checked above)
        try:
            picture = object_png(scenario, rollouts, args.object, args.challenge)
        except ValueError as error:  # e.g. an object that is not evaluated
            raise UsageError(str(error)) from None
        Path(args.output).write_bytes(picture)
        print(f"wrote {args.output} (scenario {scenario_id}, object {args.object})")
        return 0
    view = scene_view(scenario, rollouts, args.challenge)
    shown = args.rollouts
    if shown is None:  # all
        shown = list(range(view.rollouts.num_rollouts if view.rollouts is not None else 0))
    try:
        write_scene(view, args.output, step=args.step, rollouts=shown, density=args.density, every=args.every)
    except ValueError as error:  # e.g. a rollout index past the last one
        raise UsageError(str(error)) from None
    counts = ", ".join(f"{n} {label}" for label, n in view.event_counts().items())
    print(f"wrote {args.output} (scenario {scenario_id}; events over all rollouts: {counts or 'none'})")
    return 0
