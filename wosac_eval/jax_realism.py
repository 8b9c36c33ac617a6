"""Realism inside a JAX training loop (the `jax` extra): `prepare` scenes once, then `realism` on device arrays.

    from wosac_eval import jax_realism
    prepared = jax_realism.prepare(scenarios)                  # host work, once
    metrics = jax_realism.realism(prepared, x, y, z, heading)  # (num_scenes, 32, max_agents, 80) each

See `wosac_eval.backends.jax_realism` for the shapes and the Waymax-style adapter.
"""
from wosac_eval.backends.jax_realism import (  # noqa: F401
    MODES,
    SEARCHES,
    PreparedScenes,
    Realism,
    features,
    from_waymax,
    prepare,
    realism,
    stack_rollouts,
    waymax_columns,
)

from wosac_eval.backends.jax_backend import exact_cpu  # noqa: F401

__all__ = ["PreparedScenes", "Realism", "MODES", "SEARCHES", "prepare", "realism", "features", "stack_rollouts",
           "waymax_columns", "from_waymax", "exact_cpu"]
