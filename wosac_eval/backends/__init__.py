"""Compute backends for the feature kernels: "numpy" (default) and "jax" (optional extra)."""
from __future__ import annotations

BACKENDS = ("numpy", "jax")
JAX_INSTALL_HINT = "pip install 'wosac-eval[jax]'"


class BackendUnavailableError(RuntimeError):
    """The requested backend cannot run here (e.g. JAX is not installed)."""


def check_backend(name: str) -> str:
    """Validates a backend name and that its dependencies import; returns the name."""
    if name not in BACKENDS:
        raise ValueError(f"unknown backend {name!r}: choose one of {', '.join(BACKENDS)}")
    if name == "jax":
        try:
            import jax  # noqa: F401
        except ImportError as error:
            raise BackendUnavailableError(
                f"the jax backend needs JAX, which is not installed ({error}); "
                f"install it with: {JAX_INSTALL_HINT}") from error
    return name
