"""Big batches of `jax_realism` scenes without preparing them: a prepared set repeated scene by scene.

The tests lower `realism` over hundreds of scenes (abstract arrays: shapes only, no memory) and the
benchmark times it on the device (concrete arrays, gathered on the device), both from a few scenes
prepared once.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from wosac_eval import jax_realism


def _rows(base: int, num_scenes: int) -> np.ndarray:
    """Scene `s` of the tiled set is scene `s % base` of the prepared one."""
    return np.arange(num_scenes) % base


def tiled(prepared: jax_realism.PreparedScenes, num_scenes: int, abstract: bool = False) -> jax_realism.PreparedScenes:
    """`prepared`'s scenes repeated in order up to `num_scenes` scenes (its groups kept, each taking the
    copies of its scenes). `abstract`: leaves are `jax.ShapeDtypeStruct`s, for `jit(...).lower` only.
    A host search prepared set keeps its searches (each row still names its scene's)."""
    base = prepared.num_scenes
    source = _rows(base, num_scenes)
    arrays, groups = [], []
    for group_arrays, (indices, layout) in zip(prepared.arrays, prepared.groups):
        where = {scene: k for k, scene in enumerate(indices)}
        scenes = [s for s in range(num_scenes) if int(source[s]) in where]
        if not scenes:
            continue
        rows = np.asarray([where[int(source[s])] for s in scenes], np.int32)
        if abstract:
            take = lambda a: jax.ShapeDtypeStruct((rows.size,) + tuple(a.shape[1:]), a.dtype)  # noqa: E731
        else:
            take = lambda a: jnp.take(a, jnp.asarray(rows), axis=0)  # noqa: E731
        arrays.append(jax.tree_util.tree_map(take, group_arrays))
        groups.append((tuple(scenes), layout))
    return dataclasses.replace(
        prepared,
        arrays=tuple(arrays),
        groups=tuple(groups),
        scenario_ids=tuple(prepared.scenario_ids[i] for i in source),
        agent_ids=tuple(prepared.agent_ids[i] for i in source),
    )


def tiled_rollouts(arrays: dict, num_scenes: int, abstract: bool = False) -> dict:
    """`stack_rollouts`' arrays of the prepared set, repeated as `tiled` repeats its scenes."""
    base = next(iter(arrays.values())).shape[0]
    if abstract:
        return {k: jax.ShapeDtypeStruct((num_scenes,) + v.shape[1:], v.dtype) for k, v in arrays.items()}
    return {k: np.asarray(v)[_rows(base, num_scenes)] for k, v in arrays.items()}
