"""The engines work can run on ("local", "ray"), and the error of one that cannot run here.

Apart from `executors` so that the Ray executor can raise the same error
without importing the module that builds it (they imported each other).
"""
from __future__ import annotations

from wosac_eval.extras import check_choice, require_extra

ENGINES = ("local", "ray")


class EngineUnavailableError(RuntimeError):
    """The requested engine cannot run here (Ray not installed, cluster unreachable)."""


def check_engine(name: str) -> str:
    """Validates an engine name and that its dependencies import; returns the name."""
    if check_choice("engine", name, ENGINES) == "ray":
        require_extra("ray engine", "ray", "Ray", "ray", EngineUnavailableError)
    return name
