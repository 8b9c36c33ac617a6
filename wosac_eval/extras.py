"""The optional extras (`jax`, `ray`): a choice checked by name, and its package checked importable.

One check for the jax backend (`backends.check_backend`) and the ray engine
(`runtime.engines.check_engine`), so both refuse alike: a ValueError for an
unknown name, the caller's error type with the install command for a missing
package.
"""
from __future__ import annotations

import importlib
from collections.abc import Sequence


def install_hint(extra: str) -> str:
    return f"pip install 'wosac-eval[{extra}]'"


def check_choice(kind: str, name: str, choices: Sequence[str]) -> str:
    """`name` if it is one of `choices`, else a ValueError naming them (e.g. kind "backend")."""
    if name not in choices:
        raise ValueError(f"unknown {kind} {name!r}: choose one of {', '.join(choices)}")
    return name


def require_extra(what: str, module: str, package: str, extra: str, error: type[Exception]) -> None:
    """Raises `error` saying that `what` needs `package` and how to install it, unless `module` imports."""
    try:
        importlib.import_module(module)
    except ImportError as exc:
        raise error(f"the {what} needs {package}, which is not installed ({exc}); "
                    f"install it with: {install_hint(extra)}") from exc
