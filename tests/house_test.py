"""The house's rules that a reader relies on, checked on the source tree (docs/development.md)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_MODULE_LINES = 600  # a module a reader takes in at one sitting; past it, it holds more than one thing


def test_no_module_of_the_package_or_the_service_is_over_600_lines():
    modules = [*(ROOT / "wosac_eval").rglob("*.py"), *(ROOT / "server").rglob("*.py")]
    assert len(modules) > 100  # the tree was found
    long = {str(p.relative_to(ROOT)): n for p in modules if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"split these along their parts (at most {MAX_MODULE_LINES} lines each): {long}"


# The rooms held to the house's newer caps (issue 64): no module over 500 lines, no function over 80 lines,
# no function with more than 8 parameters (positional and keyword-only; self and cls aside): more is
# grouped in a dataclass or an options object. Other rooms join this list as they are split.
CAPPED_ROOMS = (
    "wosac_eval/parse",
    "wosac_eval/validate",
    "wosac_eval/results",
    "wosac_eval/sim",
    "wosac_eval/fronts",
    "benchmarks",
    "scripts",
)
CAP_MODULE_LINES, CAP_FUNCTION_LINES, CAP_PARAMETERS = 500, 80, 8


def _functions(node: ast.AST, prefix: str = ""):
    """(qualified name, node) of every function and method under `node`, nested ones included."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield prefix + child.name, child
            yield from _functions(child, f"{prefix}{child.name}.")
        elif isinstance(child, ast.ClassDef):
            yield from _functions(child, f"{prefix}{child.name}.")
        else:
            yield from _functions(child, prefix)


def _parameters(function: ast.FunctionDef | ast.AsyncFunctionDef) -> list[str]:
    arguments = function.args
    names = [a.arg for a in [*arguments.posonlyargs, *arguments.args, *arguments.kwonlyargs]]
    return names[1:] if names[:1] in (["self"], ["cls"]) else names


def test_the_capped_rooms_keep_their_modules_functions_and_signatures_small():
    modules = [p for room in CAPPED_ROOMS for p in sorted((ROOT / room).rglob("*.py"))]
    assert len(modules) > 80  # the rooms were found
    over: list[str] = []
    for path in modules:
        text = path.read_text()
        where = path.relative_to(ROOT)
        if (lines := len(text.splitlines())) > CAP_MODULE_LINES:
            over.append(f"{where}: {lines} lines (split it where its content divides)")
        for name, function in _functions(ast.parse(text)):
            length = function.end_lineno - function.lineno + 1
            if length > CAP_FUNCTION_LINES:
                over.append(f"{where}:{name}: {length} lines")
            if len(parameters := _parameters(function)) > CAP_PARAMETERS:
                over.append(f"{where}:{name}: {len(parameters)} parameters (group them in a dataclass)")
    assert not over, "over the house's caps:\n" + "\n".join(over)
