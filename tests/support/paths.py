"""Where the repository and the reference material are: the one place that knows.

The reference material (real WOMD scenarios, official configs, golden outputs of
the official implementation, the oracle scripts) sits at `../shared` beside the
repository on developer machines and in CI; `WOSAC_SHARED=/path/to/shared`
points elsewhere. A user's fresh clone has none: tests that need it skip.
"""

from __future__ import annotations

import os
from pathlib import Path

from wosac_eval.runtime.cache_dirs import user_cache_dir

REPO = Path(__file__).resolve().parents[2]
SHARED = Path(os.environ["WOSAC_SHARED"]).resolve() if os.environ.get("WOSAC_SHARED") else REPO.parent / "shared"
TEST_DATA = REPO / "tests" / "data"
# The tests' JAX compilation cache (tests/conftest.py), in the user's cache folder as pip's and numba's are.
JAX_TEST_CACHE = user_cache_dir("jax-tests")
JAX_TEST_PROGRAMS = user_cache_dir("jax-test-programs")  # their traced programs (backends/program_cache)


def shared_missing_reason(what: str = "golden") -> str | None:
    """Why a test that needs `SHARED/what` cannot run, or None when it is there."""
    if (SHARED / what).exists():
        return None
    return (
        f"{SHARED / what} is absent: the reference material (../shared, or WOSAC_SHARED) is on "
        f"developer machines and in CI, not in a user's clone"
    )


def require_shared(what: str = "golden") -> Path:
    """Skips the calling test when `SHARED/what` is absent; returns SHARED."""
    import pytest

    reason = shared_missing_reason(what)
    if reason:
        pytest.skip(reason)
    return SHARED
