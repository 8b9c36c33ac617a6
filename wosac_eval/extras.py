"""What can run here: the compute backends and the engines, and the optional extras behind them.

The backends ("numpy", "jax": the `jax` extra) compute the feature kernels;
the engines ("local", "ray": the `ray` extra) run the work. Both are checked
alike, by every front through `scoring.evaluation`: a ValueError for an unknown
name, `BackendUnavailableError` or `EngineUnavailableError` with the install
command for a missing package.
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


BACKENDS = ("numpy", "jax")
ENGINES = ("local", "ray")


class BackendUnavailableError(RuntimeError):
    """The requested backend cannot run here (e.g. JAX is not installed)."""


class EngineUnavailableError(RuntimeError):
    """The requested engine cannot run here (Ray not installed, cluster unreachable)."""


def check_backend(name: str) -> str:
    """Validates a backend name and that its dependencies import; returns the name."""
    if check_choice("backend", name, BACKENDS) == "jax":
        require_extra("jax backend", "jax", "JAX", "jax", BackendUnavailableError)
    return name


def check_engine(name: str) -> str:
    """Validates an engine name and that its dependencies import; returns the name."""
    if check_choice("engine", name, ENGINES) == "ray":
        require_extra("ray engine", "ray", "Ray", "ray", EngineUnavailableError)
    return name
