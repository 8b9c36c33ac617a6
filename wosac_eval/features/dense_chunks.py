"""Fixed-shape work in bounded pieces, for the dense (JAX) searches: rows `chunked` through `lax.map`,
and the few rows a cheaper pass left unsettled filled in a `while_loop` (`fill_rows`)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from jax import lax

# Pairs evaluated at once in the chunked searches (bounds the working memory).
PAIRS_PER_CHUNK = 1 << 22


def chunked(fn: Any, xs: Any, chunk: int) -> Any:
    """`fn` over the leading axis of the arrays `xs`, `chunk` rows at a time (via `lax.map`)."""
    n = jax.tree_util.tree_leaves(xs)[0].shape[0]
    if n <= chunk:
        return fn(xs)
    pad = (-n) % chunk
    padded = jax.tree_util.tree_map(
        lambda a: jnp.concatenate([a, jnp.zeros((pad,) + a.shape[1:], a.dtype)]) if pad else a, xs
    )
    grouped = jax.tree_util.tree_map(lambda a: a.reshape((-1, chunk) + a.shape[1:]), padded)
    out = lax.map(fn, grouped)
    return jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[2:])[:n], out)


def xyz_columns(xyz: Any) -> Any:
    """x, y, z of float32 `(..., 3)`."""
    return xyz[..., 0], xyz[..., 1], xyz[..., 2]


def rows_per_chunk(columns: int) -> int:
    return max(1, PAIRS_PER_CHUNK // max(1, columns))


def fill_rows(out: Any, which: Any, chunk: int, compute: Any) -> Any:
    """`out` with the rows where `which` is True replaced by `compute(rows)`, `chunk` rows per round.

    The rows are compacted to the front and computed in a `while_loop`, so the work follows their
    number (small: the rest was settled by cheaper means), not the array's length.

    Args:
      out: `(num_values,)` array; which: bool `(num_values,)`; compute: int32 `(batch,)` row indices ->
        `(batch,)` values.
    """
    n = which.shape[0]
    chunk = min(chunk, max(1, n))
    # The number of rows up to each one (one prefix sum, no compacted copy of the indices): a round
    # finds its rows, ranks done + 1 to done + chunk, by binary search in it.
    place = jnp.cumsum(which, dtype=jnp.int32)
    count = place[-1] if n else jnp.zeros((), jnp.int32)

    def round_(carry: Any) -> Any:
        done, out = carry
        ranks = done + jnp.arange(1, chunk + 1, dtype=jnp.int32)
        real = ranks <= count
        rows = jnp.where(real, jnp.searchsorted(place, ranks, side="left").astype(jnp.int32), 0)
        return done + chunk, out.at[jnp.where(real, rows, n)].set(compute(rows).astype(out.dtype), mode="drop")

    return lax.while_loop(lambda carry: carry[0] < count, round_, (jnp.zeros((), jnp.int32), out))[1]
