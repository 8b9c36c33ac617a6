"""Realism inside a JAX training loop (the `jax` extra): `prepare` scenes once, then `realism` on device arrays.

    from wosac_eval import jax_realism
    prepared = jax_realism.prepare(scenarios)                  # host work, once
    metrics = jax_realism.realism(prepared, x, y, z, heading)  # (num_scenes, 32, max_agents, 80) each

    # In a training step, `prepared` is an argument of your jit (closed over, it becomes constants of it):
    step = jax.jit(lambda prepared, x, y, z, heading: jax_realism.realism(prepared, x, y, z, heading))
    metrics = step(prepared, x, y, z, heading)               # or jax_realism.jit_step(step_fn, prepared)

For gradient-based training, `soft_realism(prepared, x, y, z, heading, temperature=...)` is a smooth
surrogate (a training signal, not the official metric; `wosac_eval.backends.soft_realism`).

See `wosac_eval.backends.jax_realism` for the shapes and the Waymax-style adapter.
"""

from wosac_eval.backends.jax_backend import exact_cpu
from wosac_eval.backends.jax_realism import MODES, SEARCHES, PreparedScenes, Realism, features, prepare, realism
from wosac_eval.backends.realism_inputs import from_waymax, jit_step, stack_rollouts, waymax_columns
from wosac_eval.backends.soft_realism import soft_realism

__all__ = [
    "PreparedScenes",
    "Realism",
    "MODES",
    "SEARCHES",
    "prepare",
    "realism",
    "features",
    "stack_rollouts",
    "waymax_columns",
    "from_waymax",
    "jit_step",
    "exact_cpu",
    "soft_realism",
]
