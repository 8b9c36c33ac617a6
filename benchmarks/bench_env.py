"""What every benchmark script needs: the tests' helpers (`tests/support`) on the import path,
and where the repository and the reference material (`../shared`, or WOSAC_SHARED) are."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from support.paths import REPO, SHARED  # noqa: E402,F401

# Scenarios in the WOMD validation set, which both challenges score: the projections' workload.
VALIDATION_SET = 44_097


def median_seconds(fn, repeat: int, warmup: int = 0) -> float:
    """Median wall seconds of `repeat` calls of `fn`, after `warmup` untimed calls."""
    import statistics
    import time

    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)
