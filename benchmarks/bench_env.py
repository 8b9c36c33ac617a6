"""What every benchmark script needs: the tests' helpers (`tests/support`) on the import path,
and where the repository and the reference material (`../shared`, or WOSAC_SHARED) are."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from support.paths import REPO, SHARED  # noqa: E402,F401
