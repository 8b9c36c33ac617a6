"""The dense (JAX) road-edge search: each point's nearest road-edge segment by the cell tables, and its
signed distance (`signed_distance_to_road_edge`), bit-identical to the numpy path's all-pairs pick.

Each point gathers the first segments listed for its grid cell (`road_edge.cell_candidate_table`, built
once per scene on the host, nearest first), then checks a proven bound that nothing left out can be
nearer (or tie at a lower index). The points that bound does not settle are compacted and computed
against the cell's whole list, the rare ones left against everything, in `while_loop`s (`dense_chunks`).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np
from jax import lax

from wosac_eval.features import road_edge
from wosac_eval.features.dense_chunks import chunked, fill_rows, rows_per_chunk, xyz_columns
from wosac_eval.features.spatial import NON_FINITE_PREFIX

_F = np.float32

# Queries the cell tables do not settle are searched against every segment, this many at a time.
FALLBACK_CHUNK = 256
# Queries the first `road_edge.CELL_NEAR_CANDIDATES` segments of their cell do not settle are searched
# against the cell's whole list, this many at a time.
LISTED_CHUNK = 1024
# road_edge.cell_candidate_table
CELL_KEYS = ("cell_origin", "cell_shape", "cell_candidates", "cell_clearance", "cell_near_clearance")
# `shared_segments`: the scene set's segments one table, and each scene's offset in it
SHARED_PREFIX = "shared_"
SHARED_SEGMENT_ARRAYS = ("start", "delta", "valid")
SEGMENT_OFFSET = "segment_offset"


def _nearest_segment_all(q: Any, s: Any) -> Any:
    """Index of the nearest valid segment (stretched selection distance, lowest index on ties)."""
    d3 = road_edge.segment_distances(
        *xyz_columns(q[:, None, :]), *xyz_columns(s["start"][None]), *xyz_columns(s["delta"][None])
    )[1]
    return jnp.argmin(jnp.where(s["valid"][None], d3, jnp.inf), axis=-1)


def _query_cells(q: Any, cells: Any) -> Any:
    """(grid row of each query's cell, whether the query is on the grid): int32 and bool `(num_points,)`."""
    side = _F(road_edge.CELL_SIDE)
    cell = jnp.floor((q[:, :2] - cells["cell_origin"]) / side)  # a power of two: exact
    inside = ((cell >= 0) & (cell < cells["cell_shape"].astype(_F))).all(axis=1)
    cell = jnp.where(inside[:, None], cell, _F(0)).astype(jnp.int32)
    return cell[:, 0] * cells["cell_shape"][1] + cell[:, 1], inside


def _nearest_listed_segment(q: Any, s: Any, cells: Any) -> Any:
    """(nearest segment among the query cell's listed ones, whether it is the nearest of all).

    Settled when the query is on the grid and nearer to it than the cell's clearance
    (`road_edge.cell_candidate_table`): no segment left out can be nearer, or tie at a lower index.
    """
    row, inside = _query_cells(q, cells)
    return _nearest_of(q, s, cells["cell_candidates"][row], inside, cells["cell_clearance"][row])


def _nearest_of(q: Any, s: Any, index: Any, inside: Any, clearance: Any) -> Any:
    """(nearest of the segments `index` int `(num_points, num_candidates)` to each point, the lowest index on ties;
    whether it is on the grid (`inside`) and nearer than `clearance` float32 `(num_points,)`)."""
    table, offset = _gathered_segments(s)
    index = index + offset
    d3 = road_edge.segment_distances(
        *xyz_columns(q[:, None, :]), *xyz_columns(table["start"][index]), *xyz_columns(table["delta"][index])
    )[1]
    d3 = jnp.where(table["valid"][index], d3, jnp.inf)
    big = jnp.iinfo(index.dtype).max
    # Only which segment is picked: no gradient (JAX differentiates no reduction of a custom combiner).
    best_d, best = lax.reduce((lax.stop_gradient(d3), index), (_F(np.inf), index.dtype.type(big)), _nearer, (1,))
    settled = inside & (best_d < clearance)
    return jnp.where(best == big, 0, best - offset), settled


def _gathered_segments(s: Any) -> Any:
    """(the start, delta and valid arrays the candidate lists gather from, the offset of this scene's
    segments in them): the scene set's shared tables (`shared_segments`) where given, else its own."""
    if SEGMENT_OFFSET in s:
        return {k: s[SHARED_PREFIX + k] for k in SHARED_SEGMENT_ARRAYS}, s[SEGMENT_OFFSET]
    return s, 0


def shared_segments(maps: dict) -> tuple[dict, dict]:
    """A stack of scenes' padded map arrays (leading scene axis) for `jax.vmap` with the road-edge
    segments the candidate lists gather from shared: (maps, their `in_axes`).

    Gathering a scene's own segments under `vmap` makes XLA build and store, for every point and
    candidate, a (scene, segment) index pair; from one table of every scene's segments (a reshape:
    no copy) and the scene's offset in it, each candidate is one index. The result is the same.
    """
    if "start" not in maps or "cell_candidates" not in maps:
        return maps, dict.fromkeys(maps, 0)
    scenes, count = maps["start"].shape[:2]
    shared = {SHARED_PREFIX + k: maps[k].reshape((scenes * count,) + maps[k].shape[2:]) for k in SHARED_SEGMENT_ARRAYS}
    offsets = jnp.arange(scenes, dtype=maps["cell_candidates"].dtype) * count
    axes = {**dict.fromkeys(maps, 0), **dict.fromkeys(shared), SEGMENT_OFFSET: 0}
    return {**maps, **shared, SEGMENT_OFFSET: offsets}, axes


def _nearer(a: Any, b: Any) -> Any:
    """The nearer of two (distance, segment index) pairs, the lower index on ties, NaN winning: the NaN
    minimum of the distances and the lowest index at it, as one reduction (no (points x k) array)."""
    # lax operations only: the exact mode keeps a combiner of comparisons and selects as it is.
    take = lax.lt(b[0], a[0]) | (lax.eq(b[0], a[0]) & lax.lt(b[1], a[1])) | lax.ne(b[0], b[0])
    return lax.select(take, b[0], a[0]), lax.select(take, b[1], a[1])


def _nearest_near_segment(q: Any, s: Any, cells: Any) -> Any:
    """`_nearest_listed_segment` among the first `road_edge.CELL_NEAR_CANDIDATES` listed segments, settled
    by their clearance (`cell_near_clearance`)."""
    row, inside = _query_cells(q, cells)
    index = cells["cell_candidates"][:, : road_edge.CELL_NEAR_CANDIDATES][row]
    return _nearest_of(q, s, index, inside, cells["cell_near_clearance"][row])


def _nearest_segment(queries: Any, s: Any, cells: Any, needed: Any) -> Any:
    """Index of the nearest valid road-edge segment of each needed query, as the all-pairs search picks it.

    Queries the first `road_edge.CELL_NEAR_CANDIDATES` segments of their cell settle (most) cost that
    many exact distances; the others are compacted and searched against their cell's whole list
    (`road_edge.CELL_CANDIDATES`) in a `while_loop`, LISTED_CHUNK at a time; those it does not settle
    either (off the grid, far from every road edge, on another level, NaN) against every segment,
    FALLBACK_CHUNK at a time. Unneeded queries get some segment.
    """
    best, settled = chunked(
        lambda q: _nearest_near_segment(q, s, cells),
        queries,
        rows_per_chunk(min(road_edge.CELL_NEAR_CANDIDATES, cells["cell_candidates"].shape[-1])),
    )

    def whole_list(rows: Any) -> Any:  # -1: not settled by the whole list either
        listed, listed_settled = _nearest_listed_segment(queries[rows], s, cells)
        return jnp.where(listed_settled, listed, -1)

    best = fill_rows(best, needed & ~settled, LISTED_CHUNK, whole_list)
    return fill_rows(best, needed & (best < 0), FALLBACK_CHUNK, lambda rows: _nearest_segment_all(queries[rows], s))


def signed_distance_to_road_edge(queries: Any, segments: Any, needed: Any = None) -> Any:
    """`road_edge.signed_distance_to_polylines` with fixed shapes (bit-identical on CPU).

    Args:
      queries: float32 `(num_points, 3)`.
      segments: dict of the valid road-edge segments in official order, padded:
        start, delta, prior_start, prior_delta, next_start, next_delta float32
        `(num_segments, 3)`; valid, prior_valid, next_valid, convex_before,
        convex_after bool `(num_segments,)`; and their cell table (`CELL_KEYS`, from
        `road_edge.cell_candidate_table`).
      needed: optional bool `(num_points,)`: the queries whose result is used (default all); the
        others are not searched exhaustively when the table does not settle them (their value is
        some segment's signed distance).
    Returns:
      float32 `(num_points,)`, negative on the road side.
    """
    cells = {k: jnp.asarray(segments[k]) for k in CELL_KEYS}
    fallback = {
        k[len(NON_FINITE_PREFIX) :]: jnp.asarray(v) for k, v in segments.items() if k.startswith(NON_FINITE_PREFIX)
    }
    s = {k: jnp.asarray(v) for k, v in segments.items() if k not in CELL_KEYS and not k.startswith(NON_FINITE_PREFIX)}
    finite = jnp.isfinite(queries).all(axis=1)
    needed = finite if needed is None else needed & finite
    best = _nearest_segment(queries, s, cells, needed)
    # A point with a NaN or infinite coordinate gets the official pick (`spatial.non_finite_pick`).
    pick = {k: jnp.where(finite.reshape((-1,) + (1,) * (v.ndim - 1)), s[k][best], v) for k, v in fallback.items()}
    rel_t, _, d2 = road_edge.segment_distances(
        *xyz_columns(queries), *xyz_columns(pick["start"]), *xyz_columns(pick["delta"])
    )
    xy = queries[:, :2]
    sign = road_edge.corner_sign(
        rel_t,
        road_edge.segment_side(xy, pick["start"], pick["delta"]),
        road_edge.segment_side(xy, pick["prior_start"], pick["prior_delta"]),
        road_edge.segment_side(xy, pick["next_start"], pick["next_delta"]),
        pick["convex_before"],
        pick["convex_after"],
        pick["prior_valid"],
        pick["next_valid"],
    )
    return (sign * jnp.where(pick["valid"], d2, road_edge.EXTREMELY_LARGE_DISTANCE)).astype(_F)
