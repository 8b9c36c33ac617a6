"""Float32 arithmetic no compiler may round differently: the exact mode on any device.

The official arithmetic rounds every float32 multiply, division, square root and
transcendental on its own. Compilers do not keep that on every device: XLA on a GPU
(and on a CPU with FMA) contracts a float32 multiply feeding an add into one fused
multiply-add, which rounds once; GPU compilers approximate float32 division, square
root and `exp`. Computing such an operation in float64 and rounding once gives the
correctly rounded float32 result (53 >= 2 * 24 + 2 bits), but LLVM shrinks
`float32(float64(a) * float64(b))` back to a float32 multiply (the same argument
makes that legal), which it then fuses or approximates again.

So the exact mode rewrites its traced program (`exactly_rounded`): every float32
multiply, division, root and transcendental is computed in float64 from operands
that passed through an integer XOR with a zero the program reads at run time (the
prepared scenes carry it): the value is unchanged, but no compiler can prove the
operand is a widened float32, so none shrinks the operation back, and the float32
add that reads its rounded result has no multiply beside it to fuse with. The
kernels' own float64 steps (libm `sin`, a fused multiply-add emulated in float64,
square roots and quotients through float64) widen the same way.
Float64 arithmetic itself is left to the compiler: a float64 product fused with an add
moves a float64 result by at most one float64 unit in the last place, which reaches a
float32 rounding about once in 2**29 values.

`float32_hazards(text)` lists what a lowered StableHLO module still leaves a compiler
(the test of the exact mode reads the whole realism program with it).
"""

from __future__ import annotations

import collections
import functools
import re
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax import lax
from jax.extend import core as jex

# Float32 operations whose rounding a compiler may change (fusion or approximation): computed in
# float64 from opaque operands and rounded once. Exact ones (add, min, compare, select, negate,
# rem, floor) stay float32.
WIDENED = frozenset(
    {
        "mul",
        "div",
        "sqrt",
        "rsqrt",
        "cbrt",
        "square",
        "integer_pow",
        "pow",
        "exp",
        "exp2",
        "log",
        "log1p",
        "expm1",
        "tanh",
        "logistic",
        "sin",
        "cos",
        "tan",
        "asin",
        "acos",
        "atan",
        "atan2",
        "sinh",
        "cosh",
        "asinh",
        "acosh",
        "atanh",
        "erf",
        "erfc",
        "erf_inv",
        "lgamma",
        "digamma",
    }
)
# Calls whose body is inlined into the rewritten program (XLA inlines them anyway).
INLINED = frozenset(
    {"pjit", "jit", "closed_call", "core_call", "custom_jvp_call", "custom_vjp_call", "remat", "checkpoint"}
)


def exactly_rounded(fn: Callable[..., Any]) -> Callable[..., Any]:
    """`fn(*args)` as `rewritten(zero, *args)`: every float32 multiply, division, root and transcendental
    rounded once from float64 operands no compiler can shrink back.

    `zero`: an integer scalar equal to 0 that the compiled program reads at run time (an argument of the
    jit, or a leaf of one); a constant would let the compiler see through the XOR. Call the result
    inside the caller's `jit`/`vmap` like `fn`.
    """

    @functools.wraps(fn)
    def rewritten(zero: Any, *args: Any) -> Any:
        closed, out_shape = jax.make_jaxpr(fn, return_shape=True)(*args)
        out = _eval(closed.jaxpr, closed.consts, jax.tree_util.tree_leaves(args), _as_int64(zero))
        return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(out_shape), out)

    return rewritten


def _as_int64(zero: jax.Array) -> jax.Array:
    return lax.convert_element_type(zero, np.int64)


def _is_float32(aval: Any) -> bool:
    return getattr(aval, "dtype", None) == np.float32


def opaque_float64(value: Any, zero: Any) -> jax.Array:
    """`value` as float64, through an XOR with the run-time `zero`: the same number, but no compiler
    can tell it is a widened float32 (and shrink the float64 operation it feeds back to float32)."""
    bits = lax.bitcast_convert_type(lax.convert_element_type(value, np.float64), np.int64)
    return lax.bitcast_convert_type(bits ^ zero, np.float64)


def _widened(eqn: Any, invals: Any, zero: Any) -> jax.Array:
    """The equation's float32 result computed in float64 from opaque operands and rounded once."""
    wide = [opaque_float64(value, zero) if _is_float32(var.aval) else value for var, value in zip(eqn.invars, invals)]
    return lax.convert_element_type(eqn.primitive.bind(*wide, **eqn.params), np.float32)


def _closed(closed_jaxpr: Any, zero_dtype: type[np.integer] = np.int64) -> Any:
    """A ClosedJaxpr taking the run-time zero first, then the same operands, whose body is rewritten."""
    shapes = [jax.ShapeDtypeStruct(a.shape, a.dtype, weak_type=a.weak_type) for a in closed_jaxpr.in_avals]
    body = lambda z, *a: _eval(closed_jaxpr.jaxpr, closed_jaxpr.consts, list(a), z)  # noqa: E731
    return jax.make_jaxpr(body)(jax.ShapeDtypeStruct((), zero_dtype), *shapes)


def _loop(eqn: Any, invals: Any, zero: Any) -> Any:
    """A scan, while loop or conditional whose bodies are rewritten and read the zero as a new operand."""
    params, name = dict(eqn.params), eqn.primitive.name
    if name == "scan":
        params.update(jaxpr=_closed(params["jaxpr"]), num_consts=params["num_consts"] + 1)
        if "linear" in params:
            params["linear"] = (False, *params["linear"])
        operands = [zero, *invals]
    elif name == "while":
        n = params["cond_nconsts"]
        params.update(
            cond_jaxpr=_closed(params["cond_jaxpr"]),
            cond_nconsts=n + 1,
            body_jaxpr=_closed(params["body_jaxpr"]),
            body_nconsts=params["body_nconsts"] + 1,
        )
        operands = [zero, *invals[:n], zero, *invals[n:]]
    else:  # cond: the branch index, then the branches' operands
        params.update(branches=tuple(_closed(b) for b in params["branches"]))
        operands = [invals[0], zero, *invals[1:]]
    return eqn.primitive.bind(*operands, **params)


def _holds_program(params: dict) -> bool:
    values = [v for value in params.values() for v in (value if isinstance(value, tuple) else (value,))]
    return any(isinstance(v, jex.ClosedJaxpr) for v in values)


def _inner(eqn: Any) -> tuple[Any, Any]:
    """The body of an inlined call: (jaxpr, consts)."""
    for key in ("jaxpr", "call_jaxpr", "fun_jaxpr"):
        body = eqn.params.get(key)
        if isinstance(body, jex.ClosedJaxpr):
            return body.jaxpr, body.consts
        if isinstance(body, jex.Jaxpr):
            return body, ()
    raise NotImplementedError(f"exact mode: no body found in {eqn.primitive.name}")


def _exact_combiner(eqn: Any) -> bool:
    """A reduction whose combiner (a closed jaxpr) is exact as it is: no float32 operation of `WIDENED`,
    no program inside (e.g. a minimum with its index by comparisons and selects)."""
    if eqn.primitive.name != "reduce":
        return False
    body = eqn.params.get("jaxpr")
    if not isinstance(body, jex.ClosedJaxpr):
        return False
    return not any(
        (e.primitive.name in WIDENED and any(_is_float32(v.aval) for v in e.outvars)) or _holds_program(e.params)
        for e in body.jaxpr.eqns
    )


def _eval(jaxpr: Any, consts: Any, args: list, zero: Any) -> list:
    env: dict = {}

    def read(v: Any) -> Any:
        return v.val if isinstance(v, jex.Literal) else env[v]

    env.update(zip(jaxpr.constvars, consts))
    env.update(zip(jaxpr.invars, args))
    for eqn in jaxpr.eqns:
        invals = [read(v) for v in eqn.invars]
        name = eqn.primitive.name
        out_avals = [v.aval for v in eqn.outvars]
        if name in WIDENED and any(map(_is_float32, out_avals)):
            outs = [_widened(eqn, invals, zero)]
        elif name == "convert_element_type" and _is_float32(eqn.invars[0].aval) and out_avals[0].dtype == np.float64:
            outs = [opaque_float64(invals[0], zero)]  # a kernel's own step through float64
        elif name in INLINED:
            body, body_consts = _inner(eqn)
            outs = _eval(body, body_consts, invals, zero)
        elif name in ("scan", "while", "cond"):
            outs = _loop(eqn, invals, zero)
        elif _holds_program(eqn.params) and not _exact_combiner(eqn):
            raise NotImplementedError(f"exact mode cannot rewrite the body of {name!r}")
        else:  # exact as it is (open jaxprs: a scatter's or reduction's combiner, which the check sees)
            result = eqn.primitive.bind(*invals, **eqn.params)
            outs = result if eqn.primitive.multiple_results else [result]
        for var, value in zip(eqn.outvars, outs):
            if not isinstance(var, jex.DropVar):
                env[var] = value
    return [read(v) for v in jaxpr.outvars]


# StableHLO operations whose float32 rounding a compiler may change: a multiply (contracted with the add
# it feeds into a fused multiply-add), and the divisions, roots and transcendentals it may approximate.
HAZARDOUS = (
    "multiply",
    "divide",
    "sqrt",
    "rsqrt",
    "cbrt",
    "exponential",
    "exponential_minus_one",
    "log",
    "log_plus_one",
    "logistic",
    "tanh",
    "sine",
    "cosine",
    "tan",
    "atan2",
    "power",
    "square",
    "dot_general",
    "dot",
    "convolution",
)
_OP = re.compile(r"^\s*(%[\w#]+)(?::\d+)?\s*=\s*\"?(?:stablehlo|chlo|mhlo)\.(\w+)\"?(.*)$")
_F32_RESULT = re.compile(r"(?:->|:)\s*tensor<(?:[\d?]+x)*f32>\s*$")
_WIDENING = re.compile(r"tensor<(?:[\d?]+x)*f32>\s*\)?\s*->\s*tensor<(?:[\d?]+x)*f64>\s*$")
_SHAPE_OPS = (
    "broadcast_in_dim",
    "reshape",
    "transpose",
    "slice",
    "dynamic_slice",
    "concatenate",
    "gather",
    "select",
    "pad",
)


def float32_hazards(stablehlo: str) -> collections.Counter:
    """What a lowered StableHLO module leaves a compiler free to round differently from the official float32.

    Counts by name each float32 multiply (a compiler may fuse it with an add, wherever the add is), division,
    root and transcendental, and as `shrinkable <op>` each float64 operation of those kinds with an operand
    that is visibly a widened float32 (a `convert` from f32, through shape operations only), which LLVM
    turns back into the float32 operation. Empty for the exact mode's programs.
    """
    hazards: collections.Counter = collections.Counter()
    # Per region (a function, a loop body: names are reused across regions, and an inner region reads
    # the outer ones), whether each value is visibly a float32 value as float64.
    scopes: list[dict[str, bool]] = [{}]

    def widened(name: str) -> bool:
        return next((scope[name] for scope in reversed(scopes) if name in scope), False)

    for line in stablehlo.splitlines():
        stripped = line.strip()
        if stripped.startswith("}"):  # ("} do {" closes one region and opens the next)
            scopes.pop()
        match = _OP.match(line)
        if match:
            result, op, rest = match.groups()
            operands = re.findall(r"%[\w#]+", rest.split(" : ")[0])
            scopes[-1][result] = bool(
                op == "convert" and _WIDENING.search(rest) or op in _SHAPE_OPS and any(map(widened, operands))
            )
            if op in HAZARDOUS:
                if _F32_RESULT.search(rest):
                    hazards[op] += 1
                elif any(map(widened, operands)):
                    hazards[f"shrinkable {op}"] += 1
        if stripped.endswith("{"):
            scopes.append({})
    return hazards
