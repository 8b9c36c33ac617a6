"""Running the `wosac-eval` and `wosac-server` command lines in a subprocess, as a user would."""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
from pathlib import Path

from support.paths import REPO


def console_script(name: str, module: str) -> list[str]:
    """The installed console script `name`, as a user runs it, or `python -m module` where it is not
    installed. The script imports the installed package wherever it runs, where `python -m` run in this
    repository would import the tree beside it: under a non-editable installation (CI's) a second copy,
    whose numba loops compile a second time."""
    script = Path(sysconfig.get_path("scripts")) / name
    return [str(script)] if script.is_file() else [sys.executable, "-m", module]


WOSAC_EVAL = console_script("wosac-eval", "wosac_eval.fronts.cli")
WOSAC_SERVER = console_script("wosac-server", "wosac_server")


def run_cli(*args: str, timeout: float = 600, **kwargs) -> subprocess.CompletedProcess:
    """`wosac-eval ARGS` in a fresh interpreter, output captured as text."""
    return subprocess.run(
        [*WOSAC_EVAL, *args],
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
