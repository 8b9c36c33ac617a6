"""Kernels compiled by numba for the CPU search loops: `compiled(kernel)`, one flat function per kernel.

A per-element kernel is written once with the functions of `features.ops`
(see there) and runs as is on numpy and JAX arrays. `compiled(kernel)` turns
the same source into a numba function of scalars: its syntax tree is
flattened, every kernel it calls inlined (arguments bound to fresh variables,
locals renamed) and every `ops` call replaced by its scalar expression in
`SCALAR_OPS` (the same float32 results bit for bit, NaN and the sign of zero
included). One flat function compiles in seconds, where numba's own inlining
of many small functions takes minutes, and runs as fast. numba adds no fused
multiply-add unless told to (`fastmath` is never set), so the float32
operations round exactly as numpy's.

The search loops that call compiled kernels are compiled once and cached on
disk by numba (`cached_loop`). numba tells a cached loop from a stale one by
the loop's own file only, not by the kernels or numba functions it calls from
other files, so a cached loop's name carries `KERNELS_DIGEST` (their sources), which
names numba's cache file: changed kernels make new loops, never a stale cache.
"""

from __future__ import annotations

import ast
import builtins
import collections
import copy
import functools
import hashlib
import inspect
import itertools
import math
import textwrap
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeGuard

import numba
import numpy as np

from wosac_eval.features import ops

# Each `ops` function as a scalar expression of its arguments {0}, {1}, ... (each bound to a
# variable first, so an argument may appear more than once).
SCALAR_OPS = {
    "where": "({1} if {0} else {2})",
    "sqrt": "np.sqrt({0})",
    "absolute": "abs({0})",
    "minimum": "({0} if ({0} < {1}) | ({0} != {0}) else {1})",  # numpy's loop: NaN passes on, ties give {1}
    "maximum": "({0} if ({0} > {1}) | ({0} != {0}) else {1})",
    "clip": "_clip({0}, {1}, {2})",
    "sign": "(np.float32(1) if {0} > 0 else (np.float32(-1) if {0} < 0 else (np.float32(0) if {0} == 0 else {0})))",
    "isnan": "({0} != {0})",
    "isfinite": "math.isfinite({0})",
    "divide": "({0} / {1})",
    "fma32": "np.float32(np.float64({0}) * np.float64({1}) + np.float64({2}))",
    "float32": "np.float32({0})",
    "int32": "np.int32({0})",
    "signbit": "(math.copysign(1.0, {0}) < 0)",
    "opaque": "{0}",
    "pick4": "({1} if {0} == 0 else ({2} if {0} == 1 else ({3} if {0} == 2 else {4})))",
}
_MISSING = sorted(
    name
    for name, value in vars(ops).items()
    if isinstance(value, types.FunctionType)
    and value.__module__ == ops.__name__
    and not name.startswith("_")
    and name not in SCALAR_OPS
)
assert not _MISSING, f"features.compiled lacks the scalar form of ops.{_MISSING}"


@numba.njit(inline="always")
def _clip(v: Any, low: Any, high: Any) -> Any:
    """numpy's clip of one value: the maximum with `low`, then the minimum with `high` (NaN passes on)."""
    v = v if (v > low) | (v != v) else low
    return v if (v < high) | (v != v) else high


def _is_kernel(value: object) -> bool:
    """A plain function of the feature kernels (inlined into the kernel calling it)."""
    return (
        isinstance(value, types.FunctionType)
        and value.__module__.startswith("wosac_eval.features.")
        and value.__module__ != ops.__name__
    )


@functools.cache
def _syntax(kernel: types.FunctionType) -> ast.FunctionDef:
    tree = ast.parse(textwrap.dedent(inspect.getsource(kernel)))
    (function,) = tree.body
    assert isinstance(function, ast.FunctionDef)  # a kernel is a plain `def`
    return function


class _Flattener:
    """Builds one flat function from a kernel: see the module doc."""

    def __init__(self) -> None:
        self.names = itertools.count()
        self.namespace = {"np": np, "math": math, "_clip": _clip}
        self.statements: list[ast.stmt] = []

    def fresh(self, name: str) -> str:
        return f"{name}__{next(self.names)}"

    def global_name(self, kernel: types.FunctionType, name: str) -> str:
        """A module-level value the kernel reads, under a name unique to its module."""
        value = kernel.__globals__[name] if name in kernel.__globals__ else getattr(builtins, name)
        if value is np or value is math:
            return value.__name__
        unique = f"{kernel.__module__.replace('.', '_')}__{name}"
        self.namespace[unique] = value
        return unique

    def inline(self, kernel: types.FunctionType, arguments: list[ast.expr]) -> ast.expr:
        """Appends the kernel's statements, its parameters bound to `arguments`; returns its result."""
        function = _syntax(kernel)
        params = [a.arg for a in function.args.args]
        if len(params) != len(arguments) or function.args.vararg or function.args.kwonlyargs:
            raise TypeError(f"kernel {kernel.__qualname__} is called with {len(arguments)} positional arguments")
        stores = collections.Counter(
            n.id for n in ast.walk(function) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)
        )
        local: dict[object, Any] = {}  # name -> expression or bound name; `_ASSIGNED_ONCE` -> names
        for param, argument in zip(params, arguments):
            # A constant argument (an index) stays a constant, so that what it indexes folds; a variable
            # the kernel does not reassign is read as it is (numba's compile time grows with statements).
            if isinstance(argument, ast.Constant) or _simple(argument) and not stores[param]:
                local[param] = argument
            else:
                local[param] = self.bind(param, argument)
        local[_ASSIGNED_ONCE] = {name for name, count in stores.items() if count == 1 and name not in params}
        body = function.body[1:] if _is_docstring(function.body[0]) else function.body
        for statement in body[:-1]:
            self.statement(kernel, statement, local)
        last = body[-1]
        if (
            not isinstance(last, ast.Return)
            or last.value is None
            or any(isinstance(n, ast.Return) for s in body[:-1] for n in ast.walk(s))
        ):
            raise TypeError(f"kernel {kernel.__qualname__} must end in its one return statement")
        return self.expression(kernel, last.value, local)

    def bind(self, name: str, value: ast.expr) -> str:
        """A fresh variable holding `value`."""
        fresh = self.fresh(name)
        self.statements.append(ast.Assign(targets=[ast.Name(fresh, ast.Store())], value=value, lineno=0))
        return fresh

    def statement(self, kernel: types.FunctionType, statement: ast.stmt, local: dict) -> None:
        if isinstance(statement, ast.Assign) and len(statement.targets) == 1:
            value = self.expression(kernel, statement.value, local)
            target = statement.targets[0]
            if isinstance(value, ast.Constant) and isinstance(target, ast.Name) and target.id in local[_ASSIGNED_ONCE]:
                local[target.id] = value  # a constant: substituted where it is read
                return
            self.statements.append(ast.Assign(targets=[self.target(target, local)], value=value, lineno=0))
        elif isinstance(statement, ast.For) and not statement.orelse:
            iterable = self.expression(kernel, statement.iter, local)
            target = self.target(statement.target, local)
            outer, self.statements = self.statements, []
            for inner in statement.body:
                self.statement(kernel, inner, local)
            body, self.statements = self.statements, outer
            self.statements.append(ast.For(target=target, iter=iterable, body=body, orelse=[], lineno=0))
        else:
            raise TypeError(
                f"kernel {kernel.__qualname__}: only assignments and for loops can be compiled, "
                f"not {ast.unparse(statement)!r}"
            )

    def target(self, node: ast.expr, local: dict) -> ast.expr:
        if isinstance(node, ast.Name):
            if node.id not in local:
                local[node.id] = self.fresh(node.id)
            return ast.Name(local[node.id], ast.Store())
        if isinstance(node, ast.Tuple):
            return ast.Tuple([self.target(e, local) for e in node.elts], ast.Store())
        raise TypeError(f"cannot assign to {ast.unparse(node)!r} in a compiled kernel")

    def expression(self, kernel: types.FunctionType, node: ast.expr, local: dict) -> ast.expr:
        if isinstance(node, ast.Call) and not node.keywords and not any(isinstance(a, ast.Starred) for a in node.args):
            arguments = [self.expression(kernel, a, local) for a in node.args]
            func = node.func
            if (
                isinstance(func, ast.Attribute)
                and isinstance(func.value, ast.Name)
                and func.value.id == "ops"
                and func.value.id not in local
            ):
                bound = [a if _simple(a) else ast.Name(self.bind("arg", a), ast.Load()) for a in arguments]
                text = SCALAR_OPS[func.attr].format(*(ast.unparse(a) for a in bound))
                return ast.parse(text, mode="eval").body
            if isinstance(func, ast.Name) and func.id not in local and _is_kernel(kernel.__globals__.get(func.id)):
                return self.inline(kernel.__globals__[func.id], arguments)
            return ast.Call(func=self.expression(kernel, func, local), args=arguments, keywords=[])
        if isinstance(node, ast.Call):
            raise TypeError(f"kernel {kernel.__qualname__}: calls with keywords or * cannot be compiled")
        if isinstance(node, ast.Name):
            if isinstance(local.get(node.id), ast.expr):  # a constant, or a variable read as it is
                return copy.deepcopy(local[node.id])
            return ast.Name(local[node.id] if node.id in local else self.global_name(kernel, node.id), ast.Load())
        if isinstance(node, ast.Lambda):
            raise TypeError(f"kernel {kernel.__qualname__}: lambdas cannot be compiled")
        node = type(node)(
            **{
                field: _map_field(getattr(node, field), lambda n: self.expression(kernel, n, local))
                for field in node._fields
            }
        )
        return _folded(node)


_ASSIGNED_ONCE = object()  # the key, in a kernel's locals, of the names it assigns once


def _simple(node: ast.expr) -> bool:
    """A name, a constant, or an item of a named tuple at a constant index: free to evaluate twice."""
    if isinstance(node, (ast.Name, ast.Constant)):
        return True
    return isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name) and isinstance(node.slice, ast.Constant)


_FOLDED = {
    ast.Add: lambda a, b: a + b,
    ast.Sub: lambda a, b: a - b,
    ast.Mult: lambda a, b: a * b,
    ast.BitAnd: lambda a, b: a & b,
}


def _folded(node: ast.expr) -> ast.expr:
    """Integer arithmetic on constants, and a constant tuple at a constant index, as constants: the
    indices of tuples (a box's corners) become literal, which numba reads without a memory round trip."""

    def constant_int(n: ast.expr) -> TypeGuard[ast.Constant]:
        return isinstance(n, ast.Constant) and type(n.value) is int

    if (
        isinstance(node, ast.BinOp)
        and type(node.op) in _FOLDED
        and constant_int(node.left)
        and constant_int(node.right)
    ):
        return ast.Constant(_FOLDED[type(node.op)](node.left.value, node.right.value))
    if (
        isinstance(node, ast.Subscript)
        and isinstance(node.value, ast.Tuple)
        and constant_int(node.slice)
        and all(isinstance(e, ast.Constant) for e in node.value.elts)
    ):
        index = node.slice.value
        assert isinstance(index, int)  # checked by constant_int
        element = node.value.elts[index]
        assert isinstance(element, ast.Constant)  # every element checked above
        return ast.Constant(element.value)
    return node


def _map_field(value: Any, transform: Callable[[ast.expr], ast.expr]) -> Any:
    if isinstance(value, ast.expr):
        return transform(value)
    if isinstance(value, list):
        return [_map_field(v, transform) for v in value]
    return value


def _is_docstring(statement: ast.stmt) -> bool:
    return (
        isinstance(statement, ast.Expr)
        and isinstance(statement.value, ast.Constant)
        and isinstance(statement.value.value, str)
    )


def flat_source(kernel: types.FunctionType) -> tuple[str, dict]:
    """(the source of the kernel's flat scalar function, the namespace it reads)."""
    flattener = _Flattener()
    params = [a.arg for a in _syntax(kernel).args.args]
    result = flattener.inline(kernel, [ast.Name(p, ast.Load()) for p in params])
    function = ast.FunctionDef(
        name=kernel.__name__,
        args=ast.arguments(
            posonlyargs=[], args=[ast.arg(p) for p in params], kwonlyargs=[], kw_defaults=[], defaults=[]
        ),
        body=flattener.statements + [ast.Return(result)],
        decorator_list=[],
        lineno=0,
    )
    module = ast.fix_missing_locations(ast.Module(body=[function], type_ignores=[]))
    return ast.unparse(module), flattener.namespace


@functools.cache
def compiled(kernel: types.FunctionType, inline: bool = False) -> Any:
    """`kernel` (written with `features.ops`) as a numba function of scalars (see the module doc).

    A call compiles to a call; with `inline`, numba copies the kernel into its callers, where the
    compiler can vectorise a loop around it: only for small kernels (numba's own inlining of a
    large function takes long to compile).
    """
    source, namespace = flat_source(kernel)
    exec(compile(source, f"<compiled kernel {kernel.__module__}.{kernel.__qualname__}>", "exec"), namespace)
    return numba.njit(inline="always" if inline else "never", error_model="numpy")(namespace[kernel.__name__])


# The sources of the kernels and numba functions that cached loops call (from other files, too).
_KERNEL_MODULES = (
    "ops",
    "compiled",
    "box_geometry",
    "float32_math",
    "interaction",
    "road_edge/segments",
    "road_edge/pruned_search",
    "road_edge/cell_lists",
    "road_edge/signed_distance",
    "road_edge/cell_tables",
    "traffic_lights",
)
KERNELS_DIGEST = hashlib.sha256(
    b"".join((Path(__file__).resolve().parent / f"{m}.py").read_bytes() for m in _KERNEL_MODULES)
).hexdigest()


def cached_loop(function: Callable[..., Any]) -> Any:  # Any: numba's dispatcher
    """`numba.njit(cache=True)` for a loop calling compiled kernels or numba functions of other files, named
    after the digest of their sources (`KERNELS_DIGEST`)."""
    function.__qualname__ = f"{function.__qualname__}__kernels_{KERNELS_DIGEST[:16]}"
    return numba.njit(cache=True, error_model="numpy")(function)
