"""Running the `wosac-eval` command line in a subprocess, as a user would."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from support.paths import REPO


def run_cli(*args: str, timeout: float = 600, **kwargs) -> subprocess.CompletedProcess:
    """`wosac-eval ARGS` in a fresh interpreter, output captured as text."""
    return subprocess.run(
        [sys.executable, "-m", "wosac_eval.fronts.cli", *args],
        cwd=kwargs.pop("cwd", REPO),
        capture_output=True,
        text=True,
        timeout=timeout,
        **kwargs,
    )


def run_score(tmp_path: Path, *args: str):
    """`wosac-eval score ARGS -o tmp_path/result.json`: (completed process, result or None)."""
    out = tmp_path / "result.json"
    proc = run_cli("score", *args, "-o", str(out))
    return proc, (json.loads(out.read_text()) if out.exists() else None)
