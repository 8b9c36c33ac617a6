"""What a training step hands to `jax_realism.realism`: rollouts laid out in the prepared scenes' columns
and checked, and the prepared scenes as an argument of the step's jit, not a constant of it.

- `stack_rollouts` lays out `RolloutArrays` (one per scene) on the host; `waymax_columns` and `from_waymax`
  pick the sim agents out of Waymax-style trajectories `(num_scenes, num_rollouts, num_objects, 91)`;
- `rollout_fields` checks what `realism` was given (shapes, box sizes for scenario gen) and takes any
  `__dlpack__` array without a copy; `take_scenes` gives a group of scenes its rows;
- `jit_step` binds `prepared` as the jit's first argument. A jit that closes over it instead (its arrays
  concrete while tracing) makes them constants of the compiled program (with the device search about 3 MB
  per synthetic scene, 3.8 MB per real one: 7.88 GB at 2,048 real scenes, which had not compiled after
  220 s on an H200); `realism` then warns once, in a sentence that shows the fix.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike

from wosac_eval import challenges
from wosac_eval.arrays.trajectories import index_of_ids
from wosac_eval.backends.realism_types import PreparedScenes

POSITIONS = ("x", "y", "z", "heading")
SIZES = ("length", "width", "height")


def take_scenes(fields: dict, indices: tuple) -> dict:
    rows = jnp.asarray(indices, jnp.int32)
    return {k: jnp.take(jnp.asarray(v), rows, axis=0) for k, v in fields.items()}


def _device_array(value: Any) -> Any:
    """A JAX array or tracer as it is; another `__dlpack__` producer (torch, CuPy) without a copy."""
    if isinstance(value, jax.Array) or not hasattr(value, "__dlpack__") or isinstance(value, np.ndarray):
        return value
    return jnp.from_dlpack(value)


# Closed-over prepared scenes beyond this many bytes draw `_warn_if_closed_over`'s warning (once per process).
CLOSED_OVER_WARNING_BYTES = 4 * 2**20
_closed_over_warned = False


def _under_a_jit() -> bool:
    """Whether a jit (or another staging trace) is tracing this call: it would stage an operation on
    concrete operands, where eager vmap and grad compute it."""
    # Public API only: under a staging trace even an operation on constants gives a tracer.
    return isinstance(jax.lax.add(np.int32(0), np.int32(0)), jax.core.Tracer)


def _warn_if_closed_over(prepared: PreparedScenes) -> None:
    """Warn once per process when a jit traces `realism` with `prepared`'s arrays concrete (closed over,
    not an argument), beyond `CLOSED_OVER_WARNING_BYTES`: they become constants of the program."""
    global _closed_over_warned
    if _closed_over_warned:
        return
    leaves = jax.tree_util.tree_leaves(prepared.arrays)
    if not leaves or any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
        return
    size = sum(int(np.size(leaf)) * np.dtype(leaf.dtype).itemsize for leaf in leaves)
    if size <= CLOSED_OVER_WARNING_BYTES or not _under_a_jit():
        return
    _closed_over_warned = True
    warnings.warn(
        f"jax_realism: your jax.jit closes over the {size / 1e6:.0f} MB of prepared scenes, which makes "
        f"them constants of the compiled program (slow to compile, slower to run): pass them as an "
        f"argument instead, `step = jax.jit(lambda prepared, x, y, z, heading: "
        f"jax_realism.realism(prepared, x, y, z, heading))` called as `step(prepared, x, y, z, heading)`, "
        f"or `jax_realism.jit_step(your_step, prepared)`.",
        stacklevel=4,
    )


def jit_step(step: Callable[..., Any], prepared: PreparedScenes, **jit_kwargs: Any) -> Any:
    """`jax.jit(step)` with `prepared` bound as its first argument, so the prepared scenes are an argument
    of the compiled program, not constants of it.

    `step(prepared, *args, **kwargs)` is your training (or scoring) step; `bound = jit_step(step,
    prepared)` is called as `bound(*args, **kwargs)`. `jit_kwargs` go to `jax.jit` as for `step`'s own
    signature (`prepared` is its argument 0: `donate_argnums=(1,)` donates the first of `args`).
    `bound.lower(*args, **kwargs)` lowers it (`.compile().cost_analysis()` for XLA's figures), and
    `bound.jitted` is the `jax.jit` of `step` itself.
    """
    jitted = jax.jit(step, **jit_kwargs)

    @functools.wraps(step)
    def bound(*args: Any, **kwargs: Any) -> Any:
        return jitted(prepared, *args, **kwargs)

    # Attributes on a function: mypy types `functools.wraps`' result without them.
    bound.lower = lambda *args, **kwargs: jitted.lower(prepared, *args, **kwargs)  # type: ignore[attr-defined]
    bound.jitted = jitted  # type: ignore[attr-defined]
    return bound


def rollout_fields(prepared: PreparedScenes, x: Any, y: Any, z: Any, heading: Any, sizes: dict) -> dict:
    """The rollout arrays by field, checked (shapes; box sizes exactly for scenario gen)."""
    _warn_if_closed_over(prepared)
    spec = challenges.spec(prepared.challenge)
    fields = {k: _device_array(v) for k, v in zip(POSITIONS, (x, y, z, heading))}
    sizes = {k: None if v is None else _device_array(v) for k, v in sizes.items()}
    if spec.submits_boxes:
        missing = [k for k in SIZES if sizes.get(k) is None]
        if missing:
            raise ValueError(f"scenario gen rollouts need their box sizes: {', '.join(missing)} missing")
        fields.update({k: sizes[k] for k in SIZES})
    elif any(v is not None for v in sizes.values()):
        raise ValueError("sim agents rollouts take their box sizes from the log: give no length, width, height")
    _check_rollouts(prepared, fields)
    return fields


def _check_rollouts(prepared: PreparedScenes, fields: dict) -> None:
    want = prepared.rollout_shape
    for name, value in fields.items():
        shape = tuple(np.shape(value))
        if shape[:1] + shape[2:] != want[:1] + want[2:] or len(shape) != 4:
            raise ValueError(
                f"{name} must be (num_scenes, num_rollouts, max_agents, num_steps) = "
                f"({want[0]}, num_rollouts, {want[2]}, {want[3]}) for these {prepared.challenge} "
                f"scenes, got {shape}"
            )
    rollouts = {tuple(np.shape(v))[1] for v in fields.values()}
    if len(rollouts) != 1:
        raise ValueError(f"every field must have the same number of rollouts, got {sorted(rollouts)}")


def stack_rollouts(prepared: PreparedScenes, rollouts: list) -> dict:
    """`RolloutArrays`, one per scene in order, as `realism`'s keyword arguments (numpy, host).

    Columns follow `prepared.sim_agent_ids` (padding zero); box sizes come along for scenario gen.
    """
    fields = POSITIONS + (SIZES if challenges.spec(prepared.challenge).submits_boxes else ())
    out = {f: np.zeros(prepared.rollout_shape, np.float32) for f in fields}
    for s, (ids, scene) in enumerate(zip(prepared.sim_agent_ids, rollouts)):
        real = ids[ids >= 0]
        # Each rollout may list the agents in its own order.
        columns = np.stack([index_of_ids(order, real) for order in np.asarray(scene.object_id)])
        for f in fields:
            out[f][s, :, : real.size] = np.take_along_axis(np.asarray(getattr(scene, f)), columns[..., None], axis=1)
    return out


def waymax_columns(prepared: PreparedScenes, object_ids: ArrayLike) -> np.ndarray:
    """Where each sim agent sits on a Waymax-style object axis, int32 `(num_scenes, max_agents)`.

    Args:
      object_ids: int `(num_scenes, num_objects)`, Waymax's `object_metadata.ids` (padding: any id
        that is not a sim agent's).
    Raises:
      ValueError naming the scene and the sim agents missing from its objects.
    """
    object_ids = np.asarray(object_ids)
    if object_ids.ndim != 2 or object_ids.shape[0] != prepared.num_scenes:
        raise ValueError(f"object_ids must be (num_scenes={prepared.num_scenes}, num_objects), got {object_ids.shape}")
    out = np.zeros((prepared.num_scenes, prepared.max_agents), np.int32)
    for s, ids in enumerate(prepared.agent_ids):
        where = {int(v): k for k, v in enumerate(object_ids[s])}
        missing = [i for i in ids if i not in where]
        if missing:
            raise ValueError(
                f"scenario {prepared.scenario_ids[s]}: sim agents {missing[:5]} are not among the Waymax objects"
            )
        out[s, : len(ids)] = [where[i] for i in ids]
    return out


def from_waymax(prepared: PreparedScenes, columns: Any, x: Any, y: Any, z: Any, yaw: Any, **sizes: Any) -> dict:
    """Waymax-style trajectories `(num_scenes, num_rollouts, num_objects, 91)` -> `realism`'s arguments.

    Picks the sim agents' columns (`waymax_columns`) and, for sim agents, the 80 steps after the
    current one (Waymax trajectories include the history). jit-able. Returns a dict to splat into
    `realism(prepared, **...)`.
    """
    spec = challenges.spec(prepared.challenge)
    steps = spec.simulated_steps
    pick = lambda a: jnp.take_along_axis(jnp.asarray(a), jnp.asarray(columns)[:, None, :, None], axis=2)[..., steps]  # noqa: E731
    out = {"x": pick(x), "y": pick(y), "z": pick(z), "heading": pick(yaw)}
    if spec.submits_boxes:
        out.update({k: pick(v) for k, v in sizes.items()})
    return out
