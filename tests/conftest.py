"""Fixtures for every test: the reference material in ../shared (or WOSAC_SHARED), when present."""
from __future__ import annotations

from pathlib import Path

import pytest

from support.paths import require_shared


@pytest.fixture
def shared() -> Path:
    return require_shared()


def pytest_collection_modifyitems(config, items):
    """Tests that start JAX run last: JAX runs threads, and later tests fork worker processes."""
    uses_jax = ("jax_backend_test.py", "test_jax_kernels.py", "test_score_backends.py", "jax_realism_test.py")
    items.sort(key=lambda item: item.path.name in uses_jax)
