"""The house's rules that a reader relies on, checked on the source tree (docs/development.md)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_MODULE_LINES = 600  # a module a reader takes in at one sitting; past it, it holds more than one thing


def test_no_module_of_the_package_or_the_service_is_over_600_lines():
    modules = [*(ROOT / "wosac_eval").rglob("*.py"), *(ROOT / "server").rglob("*.py")]
    assert len(modules) > 100  # the tree was found
    long = {str(p.relative_to(ROOT)): n for p in modules if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"split these along their parts (at most {MAX_MODULE_LINES} lines each): {long}"
