"""Compute backends for the feature kernels: "numpy" (default) and "jax" (optional extra)."""
from __future__ import annotations

from wosac_eval.extras import check_choice, require_extra

BACKENDS = ("numpy", "jax")


class BackendUnavailableError(RuntimeError):
    """The requested backend cannot run here (e.g. JAX is not installed)."""


def check_backend(name: str) -> str:
    """Validates a backend name and that its dependencies import; returns the name."""
    if check_choice("backend", name, BACKENDS) == "jax":
        require_extra("jax backend", "jax", "JAX", "jax", BackendUnavailableError)
    return name
