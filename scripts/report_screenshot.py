"""Regenerates the report screenshot of the user guide (docs/report.png); needs Chromium.

    python scripts/report_screenshot.py [OUT_DIR] [--png docs/report.png]

Writes the gate demo's results and report into OUT_DIR (default a temporary
folder) and renders the report in headless Chromium.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from support import browser  # noqa: E402
from wosac_eval.fronts.commands.demo import run_gate_demo  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", type=Path, nargs="?")
    parser.add_argument("--png", type=Path, default=REPO / "docs" / "report.png")
    args = parser.parse_args()
    out = args.out_dir or Path(tempfile.mkdtemp(prefix="wosac-report-"))
    code = run_gate_demo(out)
    if code == 0:
        browser.screenshot(out / "report.html", args.png, width=1280, height=2000, palette_colors=96)
        print(f"wrote {args.png}")
    return code


if __name__ == "__main__":
    raise SystemExit(main())
