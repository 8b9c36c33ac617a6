"""The house's rules that a reader relies on, checked on the source tree (docs/development.md).

- The rooms of `wosac_eval/` in the order docs/development.md's layout lists them: each imports only
  from the rooms before it (every import of the package, those inside functions and under
  `TYPE_CHECKING` included), and no modules import each other in a circle.
- No module over 500 lines, no function over 80 lines, none with more than 8 parameters, in
  `wosac_eval/`, `server/` and `benchmarks/`.
- Every function of `wosac_eval/` annotates each parameter and its return (mypy's
  `disallow_untyped_defs` for the package, pyproject.toml; checked here too, where a reader looks).
- One vocabulary of axis names: every backticked shape in the docstrings of `wosac_eval/` and `server/`
  names its axes from the tables of docs/extending.md's "Axis names" (numbers and `...` besides).
"""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "wosac_eval"
LAYOUT = ROOT / "docs" / "development.md"
AXES_DOC = ROOT / "docs" / "extending.md"  # its "Axis names" tables: the vocabulary of shapes in docstrings
MAX_MODULE_LINES = 500  # a module a reader takes in at one sitting; past it, it holds more than one thing
MAX_FUNCTION_LINES = 80  # a function read at once, on one screen or two
MAX_PARAMETERS = 8  # past it, what travels together goes as one dataclass, named tuple or options object
GENERATED = ("wosac_eval/protos/",)  # protoc's output

# The parts of the tree the caps are checked on, one test each. A part still being split would be named in
# PENDING, its tests marked xfail(strict=True), so that the mark must go once the part meets the cap (a
# strict xfail that passes fails); none is.
PARTS = {
    "wosac_eval (features ... arrays, top-level modules)": (
        "wosac_eval/features",
        "wosac_eval/backends",
        "wosac_eval/analysis",
        "wosac_eval/metrics",
        "wosac_eval/estimators",
        "wosac_eval/scoring",
        "wosac_eval/runtime",
        "wosac_eval/arrays",
        "wosac_eval/__init__.py",
        "wosac_eval/options.py",
        "wosac_eval/challenges.py",
        "wosac_eval/metric_table.py",
        "wosac_eval/extras.py",
        "wosac_eval/jax_realism.py",
    ),
    "wosac_eval/parse": ("wosac_eval/parse",),
    "wosac_eval/validate": ("wosac_eval/validate",),
    "wosac_eval/results": ("wosac_eval/results",),
    "wosac_eval/compat": ("wosac_eval/compat",),
    "wosac_eval/sim": ("wosac_eval/sim",),
    "wosac_eval/client": ("wosac_eval/client",),
    "wosac_eval/fronts": ("wosac_eval/fronts",),
    "server": ("server",),
    "benchmarks": ("benchmarks",),
}
_SPLIT_BESIDE = "issue 64: {part} is not within the cap yet, its split another change's share of the issue: drop this mark once it is"
PENDING: dict[str, tuple[str, ...]] = {"modules": (), "functions": (), "parameters": ()}
# Functions of the first part kept over the parameter cap, each with its reason. The list may only shrink:
# a function that comes under the cap fails the test until its entry goes.
WIDE_FUNCTIONS = {
    # Public signatures that users call with the official trajectory fields as arrays (docs/*.md).
    "wosac_eval/arrays/messages.py:rollouts_from_arrays": "public: the arrays of the official trajectory fields",
    "wosac_eval/arrays/messages.py:joint_scene": "public: the arrays of the official trajectory fields",
    "wosac_eval/backends/jax_realism.py:realism": "public (docs/jax.md): the rollouts' arrays by field",
    "wosac_eval/backends/jax_realism.py:features": "public (docs/jax.md): the rollouts' arrays by field",
    "wosac_eval/backends/soft_realism.py:soft_realism": "public (docs/jax.md): the rollouts' arrays by field",
    # Not regrouped yet: the box arrays of the nearest-object and road-edge searches (a `Boxes` of x, y,
    # length, width, cos, sin, valid through the search strategies), the scalar kernels that `compiled`
    # flattens for numba, and the compiled loops over them (their speed measured by score_speed.py).
    "wosac_eval/features/interaction.py:box_pair_distance": "a compiled scalar kernel: two boxes' values",
    "wosac_eval/features/following.py:frame_offsets": "a compiled scalar kernel: two boxes' values",
    "wosac_eval/features/road_edge/segments.py:segment_distances": "a compiled scalar kernel: a point, a segment",
    "wosac_eval/features/interaction.py:_nearest_object_search": "a compiled loop over the box arrays",
    "wosac_eval/features/following.py:_followed_search": "a compiled loop over the box arrays",
    "wosac_eval/features/traffic_lights.py:_crossings": "a compiled loop over the positions and stop lines",
    "wosac_eval/analysis/criticality_features.py:_pair_entries": "a compiled loop over the pairs' arrays",
    "wosac_eval/features/interaction.py:distance_to_nearest_object": "the box arrays, not yet one Boxes",
    "wosac_eval/features/interaction.py:_nearest_object_chunk": "the box arrays, not yet one Boxes",
    "wosac_eval/features/road_edge/signed_distance.py:box_distance_to_road_edge": "the box arrays, not yet one Boxes",
    "wosac_eval/features/dense.py:_nearest_object_candidates": "the box arrays, not yet one Boxes",
    "wosac_eval/features/dense.py:time_to_collision": "the box arrays, not yet one Boxes",
    # The official API's own signatures, which programs written for it call by keyword (docs/official-api.md).
    "wosac_eval/compat/interaction_features.py:compute_distance_to_nearest_object": "the official signature",
    "wosac_eval/compat/map_metric_features.py:compute_distance_to_road_edge": "the official signature",
    "wosac_eval/compat/visualizations.py:get_animated_states": "the official signature",
}


# --- The rooms and their imports --------------------------------------------------------------------


def documented_rooms() -> list[str]:
    """The rooms of the package (`wosac_eval/x/` folders and `wosac_eval/x.py` modules), in the order of
    docs/development.md's layout block."""
    layout = LAYOUT.read_text().split("## Layout\n", 1)[1]
    block = layout.split("```text\n", 1)[1].split("```", 1)[0]
    return [line.split()[0] for line in block.splitlines() if line.startswith(f"{PACKAGE}/")]


def room_of(path: str, rooms: list[str]) -> str | None:
    """The room holding a file of the package (a path relative to the repository), or None."""
    if path in rooms:
        return path
    folders = [room for room in rooms if room.endswith("/") and path.startswith(room)]
    return max(folders, key=len) if folders else None


def module_path(module: str) -> str | None:
    """The file of a module of the package (its `__init__.py` for a package), or None."""
    base = ROOT / Path(*module.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate.relative_to(ROOT).as_posix()
    return None


def imported_files(path: str) -> list[tuple[int, str]]:
    """(line, file) of every module of the package that the file imports, anywhere in it: `from p import m`
    names the module `p.m` where there is one, else `p` itself."""
    source = ROOT / path
    package = ".".join(Path(path).with_suffix("").parts[:-1])
    found = []
    for node in ast.walk(ast.parse(source.read_text(), str(source))):
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the file's own package up
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            modules = [f"{base}.{alias.name}" if module_path(f"{base}.{alias.name}") else base for alias in node.names]
        else:
            continue
        for module in modules:
            if module.split(".")[0] == PACKAGE and (target := module_path(module)) is not None:
                found.append((node.lineno, target))
    return found


@functools.cache
def package_files() -> tuple[str, ...]:
    files = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / PACKAGE).rglob("*.py"))
    return tuple(f for f in files if not f.startswith(GENERATED))


@functools.cache
def import_graph() -> dict[str, tuple[tuple[int, str], ...]]:
    return {f: tuple(imported_files(f)) for f in package_files()}


def test_the_layout_lists_every_room_once():
    rooms = documented_rooms()
    assert len(rooms) > 15, "docs/development.md's layout block was not found"
    assert len(set(rooms)) == len(rooms), f"listed twice: {sorted({r for r in rooms if rooms.count(r) > 1})}"
    unplaced = [f for f in package_files() if room_of(f, rooms) is None]
    assert not unplaced, f"add their room to docs/development.md's layout, in its place: {unplaced}"
    missing = [r for r in rooms if not (ROOT / r).exists()]
    assert not missing, f"the layout lists rooms that do not exist: {missing}"


def test_each_room_imports_only_from_the_rooms_before_it():
    rooms = documented_rooms()
    back = [
        f"{source}:{line} ({room_of(source, rooms)}) imports {target} ({room_of(target, rooms)})"
        for source, imports in import_graph().items()
        for line, target in imports
        if rooms.index(room_of(target, rooms)) > rooms.index(room_of(source, rooms))
    ]
    assert not back, "imports that run back up the documented order:\n" + "\n".join(back)


def test_no_modules_import_each_other_in_a_circle():
    graph = {source: sorted({target for _, target in imports} - {source}) for source, imports in import_graph().items()}
    circles = [sorted(c) for c in strongly_connected(graph) if len(c) > 1]
    assert not circles, f"modules that import each other in a circle: {circles}"


def strongly_connected(graph: dict[str, list[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components of a directed graph (iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(graph.get(root, ())))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, edges = work[-1]
            following = next(edges, None)
            if following is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    components.append(component)
            elif following not in index:
                index[following] = low[following] = len(index)
                stack.append(following)
                on_stack.add(following)
                work.append((following, iter(graph.get(following, ()))))
            elif following in on_stack:
                low[node] = min(low[node], index[following])
    return components


def test_the_import_checks_see_what_they_check():
    """The checks above find the arrows and circles they are about, on a small graph and on the tree."""
    assert sorted(map(sorted, strongly_connected({"a": ["b"], "b": ["c", "a"], "c": [], "d": ["d"]}))) == [
        ["a", "b"],
        ["c"],
        ["d"],
    ]
    scoring = dict(import_graph()["wosac_eval/scoring/submission.py"])
    assert "wosac_eval/validate/__init__.py" in scoring.values()  # `from wosac_eval.validate import ...`
    assert "wosac_eval/analysis/criticality_cache.py" in scoring.values()  # `from wosac_eval.analysis import m`
    # An import inside a function counts (the optional extras' are kept there).
    assert "wosac_eval/runtime/ray_executor.py" in dict(import_graph()["wosac_eval/runtime/executors.py"]).values()


# --- The caps ------------------------------------------------------------------------------------------


def part_files(part: str) -> list[Path]:
    files = []
    for entry in PARTS[part]:
        path = ROOT / entry
        files += [path] if path.is_file() else sorted(path.rglob("*.py"))
    return [f for f in files if not f.relative_to(ROOT).as_posix().startswith(GENERATED)]


def functions(path: Path):
    """(name, lines, parameters) of every function and method of a file (`self` and `cls` not counted)."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = node.args
            names = [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)] + [
                p.arg for p in (a.vararg, a.kwarg) if p is not None
            ]
            if names[:1] in (["self"], ["cls"]):
                names = names[1:]
            yield node.name, node.end_lineno - node.lineno + 1, len(names)


def capped(rule: str):
    """The parts as test parameters, those still being split beside this change marked xfail(strict=True)."""
    return [
        pytest.param(
            part,
            marks=pytest.mark.xfail(strict=True, reason=_SPLIT_BESIDE.format(part=part))
            if part in PENDING[rule]
            else (),
        )
        for part in PARTS
    ]


def test_the_parts_cover_the_package():
    covered = {f for part in PARTS for f in part_files(part)}
    missed = [f for f in package_files() if ROOT / f not in covered]
    assert not missed, f"add them to a part of PARTS: {missed}"


@pytest.mark.parametrize("part", capped("modules"))
def test_no_module_is_over_500_lines(part):
    files = part_files(part)
    assert files, part
    long = {str(p.relative_to(ROOT)): n for p in files if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"split these along their parts (at most {MAX_MODULE_LINES} lines each): {long}"


@pytest.mark.parametrize("part", capped("functions"))
def test_no_function_is_over_80_lines(part):
    long = {
        f"{p.relative_to(ROOT)}:{name}": lines
        for p in part_files(part)
        for name, lines, _ in functions(p)
        if lines > MAX_FUNCTION_LINES
    }
    assert not long, f"split these into functions of at most {MAX_FUNCTION_LINES} lines: {long}"


@pytest.mark.parametrize("part", capped("parameters"))
def test_no_function_has_more_than_8_parameters(part):
    wide = {
        f"{p.relative_to(ROOT)}:{name}": count
        for p in part_files(part)
        for name, _, count in functions(p)
        if count > MAX_PARAMETERS
    }
    kept = {name for name in WIDE_FUNCTIONS if name.startswith(PARTS[part])}
    assert not set(wide) - kept, (
        f"at most {MAX_PARAMETERS} parameters (what travels together as one dataclass, named tuple or options "
        f"object): { ({k: v for k, v in wide.items() if k not in kept}) }"
    )
    assert not kept - set(wide), f"now within the cap: drop them from WIDE_FUNCTIONS: {sorted(kept - set(wide))}"


# --- Annotations ---------------------------------------------------------------------------------------


def unannotated(path: Path) -> list[str]:
    """`file:line name (what)` of every function of a file that leaves a parameter (but `self` and `cls`) or
    its return unannotated."""
    found = []
    where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        a = node.args
        params = [*a.posonlyargs, *a.args, *a.kwonlyargs, *(p for p in (a.vararg, a.kwarg) if p is not None)]
        missing = [p.arg for p in params if p.annotation is None and p.arg not in ("self", "cls")]
        missing += ["return"] if node.returns is None else []
        if missing:
            found.append(f"{where}:{node.lineno} {node.name} ({', '.join(missing)})")
    return found


def test_the_annotation_check_sees_what_it_checks(tmp_path):
    """A missing parameter, `*args` or return annotation is reported; `self` needs none."""
    source = tmp_path / "module.py"
    source.write_text("class A:\n    def f(self, x: int, *args) -> int: ...\ndef g(y: str): ...\n")
    names = sorted(entry.split(" ", 1)[1] for entry in unannotated(source))
    assert names == ["f (args)", "g (return)"]


def test_every_function_of_the_package_is_annotated():
    files = [ROOT / f for f in package_files()]
    missing = [entry for p in files for entry in unannotated(p)]
    assert not missing, f"annotate every parameter and the return of these ({len(missing)}): {missing[:50]}"


# --- Axis names ----------------------------------------------------------------------------------------

_SPAN = re.compile(r"`([^`]*)`")  # a backticked span of a docstring
_TUPLE = re.compile(r"(?<![\w.\])])\(([^()]*)\)")  # parentheses not closing a call or an index
_AXIS = re.compile(r"\.\.\.|[A-Za-z_]\w*|\d+")
# Words that mark a tuple as a shape besides the vocabulary itself: the retired spellings of its axes.
_RETIRED = {"samples", "objects", "steps", "agents", "rollouts", "signals", "evaluated", "scenes", "entries"}


@functools.cache
def axis_names() -> frozenset[str]:
    """The names of the tables of docs/extending.md's "Axis names" section (their first column)."""
    section = AXES_DOC.read_text().split("## Axis names\n", 1)[1].split("\n## ", 1)[0]
    return frozenset(re.findall(r"^\| `([a-z_]+)` \|", section, re.MULTILINE))


def shape_axes(docstring: str):
    """(line offset, axes) of every backticked tuple of the docstring that reads as a shape: all its parts
    names, numbers or `...`, and one of them a number, `...`, a count (`num_`, `n_`, `max_`), a listed name
    or a retired one, or a single part with its comma, `(num_objects,)`. Value tuples such as `(low, high)`
    are not shapes."""
    for span in _SPAN.finditer(docstring):
        for found in _TUPLE.finditer(span.group(1)):
            parts = [p.strip() for p in found.group(1).split(",")]
            single = len(parts) == 2 and parts[1] == ""
            parts = parts[:-1] if single else parts
            if len(parts) < 2 and not single or not all(_AXIS.fullmatch(p) for p in parts):
                continue
            marked = [p for p in parts if p in axis_names() or p in _RETIRED or p == "..." or p.isdigit()]
            if single or marked or any(p.startswith(("num_", "n_", "max_")) for p in parts):
                yield docstring.count("\n", 0, span.start()), parts


def odd_axes(path: Path) -> list[str]:
    """`file:line: axis` of every axis of a docstring shape that is neither listed, a number nor `...`."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        first = node.body[0] if node.body else None
        if not (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)):
            continue
        if not isinstance(first.value.value, str):
            continue
        for offset, parts in shape_axes(first.value.value):
            odd = [p for p in parts if not (p in axis_names() or p == "..." or p.isdigit())]
            found += [f"{path.relative_to(ROOT)}:{first.value.lineno + offset}: {p}" for p in odd]
    return found


def test_the_axis_names_are_listed():
    """The vocabulary's tables hold the axes of the trajectories (and no retired spelling)."""
    assert {"num_rollouts", "num_samples", "num_objects", "num_evaluated", "num_steps", "batch"} <= axis_names()
    assert not axis_names() & _RETIRED


def test_the_axis_check_sees_what_it_checks():
    """Shapes are found in backticks, value tuples and calls are not; odd axes are reported."""
    doc = "x: `(num_samples, n_objects, steps)`; y: `(num_pairs,)`\n`(low, high)`, `f(a, b)`, (samples, steps)"
    assert [parts for _, parts in shape_axes(doc)] == [["num_samples", "n_objects", "steps"], ["num_pairs"]]
    assert [parts for _, parts in shape_axes("`(..., num_objects, 91)` and `(batch,)`")] == [
        ["...", "num_objects", "91"],
        ["batch"],
    ]


@pytest.mark.parametrize("folder", ["wosac_eval", "server"])
def test_docstring_shapes_use_the_axis_names(folder):
    files = [
        p for p in sorted((ROOT / folder).rglob("*.py")) if not p.relative_to(ROOT).as_posix().startswith(GENERATED)
    ]
    assert files, folder
    odd = [entry for p in files for entry in odd_axes(p)]
    assert not odd, f'name these axes from docs/extending.md\'s "Axis names" (or list a new one there): {odd}'
