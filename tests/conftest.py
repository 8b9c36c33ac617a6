"""Shared fixtures: the reference material in ../shared, when present."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


def require_shared() -> Path:
    if not (SHARED / "golden").is_dir():
        pytest.skip("../shared/golden is absent: golden parity needs the official reference outputs "
                    "(present on developer machines and in CI, not in a user's clone)")
    return SHARED


def run_score(tmp_path: Path, *args: str):
    """`wosac-eval score ARGS -o tmp_path/result.json` in a subprocess: (completed process, result or None)."""
    out = tmp_path / "result.json"
    proc = subprocess.run([sys.executable, "-m", "wosac_eval.fronts.cli", "score", *args, "-o", str(out)],
                          cwd=REPO, capture_output=True, text=True, timeout=600)
    return proc, (json.loads(out.read_text()) if out.exists() else None)


@pytest.fixture
def shared() -> Path:
    return require_shared()


def pytest_collection_modifyitems(config, items):
    """Tests that start JAX run last: JAX runs threads, and later tests fork worker processes."""
    uses_jax = ("test_jax_backend.py", "test_jax_kernels.py", "test_score_backends.py")
    items.sort(key=lambda item: item.path.name in uses_jax)
