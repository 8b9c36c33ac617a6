"""Shared fixtures: the reference material in ../shared, when present."""
from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


def require_shared() -> Path:
    if not (SHARED / "golden").is_dir():
        pytest.skip("../shared/golden is absent: golden parity needs the official reference outputs "
                    "(present on developer machines and in CI, not in a user's clone)")
    return SHARED


@pytest.fixture
def shared() -> Path:
    return require_shared()


def pytest_collection_modifyitems(config, items):
    """Tests that start JAX run last: JAX runs threads, and later tests fork worker processes."""
    uses_jax = ("test_jax_backend.py", "test_jax_kernels.py", "test_score_backends.py")
    items.sort(key=lambda item: item.path.name in uses_jax)
