"""Demo results for trying `compare` / `report` without a simulator, and the docs screenshot.

    python -m wosac_eval.fronts.gate.demo OUT_DIR

Writes OUT_DIR/baseline.json and OUT_DIR/new.json (synthetic results of 2000
scenarios: in the new run the collision likelihood and rate improve, the offroad
likelihood gets worse, and 10 scenarios were skipped) and OUT_DIR/report.html.
`scripts/report_screenshot.py` renders that report to the docs' PNG.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from wosac_eval.fronts.gate.synthetic import result_json, synthetic_scenarios

TITLE = "WOSAC realism: my-sim (PR) vs baseline (main)"


def write_demo_results(folder: Path, num_scenarios: int = 2000) -> tuple[Path, Path]:
    """Writes baseline.json and new.json into `folder` and returns their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    base = synthetic_scenarios(num_scenarios, seed=0)
    new = synthetic_scenarios(num_scenarios, seed=0, jitter=0.02, jitter_seed=7, shift={
        "collision_indication_likelihood": 0.012, "offroad_indication_likelihood": -0.006,
        "simulated_collision_rate": -0.004})
    kept = num_scenarios - 10
    skipped = [{"scenario_id": s["scenario_id"], "reason": "no rollouts in the submission (scored with --partial)"}
               for s in new[kept:]]
    base_path, new_path = folder / "baseline.json", folder / "new.json"
    base_path.write_text(json.dumps(result_json(base)))
    new_path.write_text(json.dumps(result_json(new[:kept], skipped=skipped)))
    return base_path, new_path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", type=Path)
    args = parser.parse_args(argv)
    write_demo_results(args.out_dir)
    from wosac_eval.fronts.cli import main as cli

    # Run from the folder so that the report shows short file names.
    here = os.getcwd()
    os.chdir(args.out_dir)
    try:
        return cli(["report", "new.json", "--compare", "baseline.json", "--html", "report.html", "--title", TITLE])
    finally:
        os.chdir(here)


if __name__ == "__main__":
    raise SystemExit(main())
