"""What can run here: the compute backends and the engines, and the optional extras behind them.

The backends ("numpy", "jax": the `jax` extra) compute the feature kernels;
the engines ("local", "ray": the `ray` extra) run the work. Both are checked
alike, by every front through `scoring.evaluation`: a ValueError for an unknown
name, `BackendUnavailableError` or `EngineUnavailableError` with the install
command for a missing package.
"""

from __future__ import annotations

import importlib

from wosac_eval.options import Backend, Engine


def install_hint(extra: str) -> str:
    return f"pip install 'wosac-eval[{extra}]'"


def require_extra(what: str, module: str, package: str, extra: str, error: type[Exception]) -> None:
    """Raises `error` saying that `what` needs `package` and how to install it, unless `module` imports."""
    try:
        importlib.import_module(module)
    except ImportError as exc:
        raise error(
            f"the {what} needs {package}, which is not installed ({exc}); install it with: {install_hint(extra)}"
        ) from exc


BACKENDS = Backend.names()
ENGINES = Engine.names()


class BackendUnavailableError(RuntimeError):
    """The requested backend cannot run here (e.g. JAX is not installed)."""


class EngineUnavailableError(RuntimeError):
    """The requested engine cannot run here (Ray not installed, cluster unreachable)."""


class EngineNotInstalledError(EngineUnavailableError):
    """The requested engine's package is not installed: unlike an unreachable cluster, no retry brings it."""


class EngineAuthenticationError(EngineUnavailableError):
    """The cluster turned away this process's credentials (no token, or another one): a retry would send
    the same, so none is made."""


def check_backend(name: str) -> Backend:
    """Validates a backend name (`Backend.parse`) and that its dependencies import; returns the member."""
    backend = Backend.parse(name)
    if backend is Backend.JAX:
        require_extra("jax backend", "jax", "JAX", "jax", BackendUnavailableError)
    return backend


def check_engine(name: str) -> Engine:
    """Validates an engine name (`Engine.parse`) and that its dependencies import; returns the member."""
    engine = Engine.parse(name)
    if engine is Engine.RAY:
        require_extra("ray engine", "ray", "Ray", "ray", EngineNotInstalledError)
    return engine
