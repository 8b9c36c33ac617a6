"""JAX drivers of the feature kernels: fixed shapes; the road-edge search pruned by tables, exact by a fallback.

The numpy path prunes candidate pairs in compiled loops over bucket grids and
bounds (a k-d tree for the lane search), whose work depends on the data. Under
`jax.jit` shapes must be static, so these drivers evaluate the SAME per-pair
kernels (box_geometry, road_edge, traffic_lights, interaction) over fixed-size
candidate sets. For the road edge, each corner gathers the first segments
listed for its grid cell (`road_edge.cell_candidate_table`, built once per scene
on the host, nearest first), then checks a proven bound that nothing left out
can be nearer (or tie at a lower index). The queries that bound does not settle
are compacted and computed against the cell's whole list, the rare ones left
against everything, in `while_loop`s, so results equal an
all-pairs search (`argmin`: the first index among ties, as in the numpy path) bit
for bit. The nearest object evaluates the few boxes of lowest bound (the numpy
search's bound) and falls back likewise where the bound does not settle it.
Time to collision stays all-pairs (evaluated objects x all objects, a cheap
kernel, reduced as the pairs are computed), and so does the red-light lane
search (over crossing points only).

The road-edge search is `dense_road_edge`'s, the bounded pieces of work (`lax.map` chunks,
`while_loop` fills) `dense_chunks`'s.

Everything here expects float32 inputs that are already padded (invalid
padding masked by the `valid` arrays). The float32 math rounds a few steps
through `xp.wide_float` (float64 under x64; float32 in `xp.float32_precision()`).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from wosac_eval.features import box_geometry, following, interaction, road_edge, traffic_lights
from wosac_eval.features.dense_chunks import chunked, fill_rows, rows_per_chunk
from wosac_eval.features.dense_road_edge import signed_distance_to_road_edge
from wosac_eval.features.float32_math import sincos32
from wosac_eval.features.search_strategy import TimeToCollisionInputs
from wosac_eval.features.spatial import strict_argmin
from wosac_eval.features.xp import in_differentiable, nan_spreading_max, nan_spreading_min

_F = np.float32
# Boxes evaluated exactly per (evaluated object, step) before the bound decides: the pruned search
# evaluates 1.3 per query on a real scene; rows these do not settle are searched against every box.
NEAREST_OBJECT_CANDIDATES = 4
# Rows searched against every box at once, in the nearest-object fallback's `while_loop`.
NEAREST_OBJECT_FALLBACK_CHUNK = 128


def _nearest_object_all_pairs(outlines: Any, radius: Any, valid: Any, rows: Any, steps: Any) -> Any:
    """The official all-pairs nearest-object distance of the boxes `rows` at `steps` (each `(batch,)`).

    Every pair; the self pair offset by 1e10 (a NaN box stays NaN), invalid pairs 1e10, the minimum
    passing NaN on, capped at 1e10. `outlines`, `radius`, `valid`: `(num_objects, num_steps, ...)`.
    """
    at_step = lambda v: jnp.swapaxes(v[:, steps], 0, 1)  # noqa: E731  (chunk, num_objects, ...)
    a = tuple(jnp.broadcast_to(v[rows, steps][:, None], at_step(v).shape) for v in outlines)
    b = tuple(at_step(v) for v in outlines)
    d = interaction.outline_distance(a, b, radius[rows, steps][:, None], at_step(radius))
    self_pair = rows[:, None] == jnp.arange(radius.shape[0])[None]
    d = jnp.where(self_pair, d + interaction.EXTREMELY_LARGE_DISTANCE, d)
    d = jnp.where(valid[rows, steps][:, None] & at_step(valid), d, interaction.EXTREMELY_LARGE_DISTANCE)
    return jnp.minimum(nan_spreading_min(d, axis=1), interaction.EXTREMELY_LARGE_DISTANCE)


def _lowest_k(values: Any, count: int) -> Any:
    """The `count` lowest of `values` along the last axis, ascending, the lower index first on ties:
    (values, indices), each with `count` along the last axis. By `count` minimum passes: XLA's CPU `top_k` sorts whole
    rows when its results feed more than one computation (4x slower here); `values` has no NaN."""
    columns = jnp.arange(values.shape[-1])
    lowest, picks = [], []
    for _ in range(count):
        pick = jnp.argmin(values, axis=-1)
        lowest.append(jnp.take_along_axis(values, pick[..., None], axis=-1)[..., 0])
        picks.append(pick)
        values = jnp.where(columns == pick[..., None], jnp.inf, values)
    return jnp.stack(lowest, axis=-1), jnp.stack(picks, axis=-1)


def _nearest_object_candidates(
    x: Any,
    y: Any,
    length: Any,
    width: Any,
    cos_h: Any,
    sin_h: Any,
    outlines: Any,
    radius: Any,
    valid: Any,
    num_evaluated: int,
) -> Any:
    """(distance, settled), float32 and bool `(num_evaluated, num_steps)`: the pruned search's
    answer from the `NEAREST_OBJECT_CANDIDATES` boxes of lowest bound, and where it is proven.

    As `interaction._nearest_object_search`: the bound of a pair is the centres' distance less both
    bounding radii, with float32 margins; the box of lowest bound (first index on ties) is evaluated,
    then every box whose bound does not exclude its distance. A row is settled when those boxes are
    among the candidates (the next bound is above the threshold) and no valid box at its step is one
    whose pairs are all evaluated (`interaction.exhaustive_boxes`).
    """
    k = NEAREST_OBJECT_CANDIDATES
    e = slice(0, num_evaluated)
    reach = interaction.bounding_reach(length, width, valid)
    dx, dy = x[None] - x[e, None], y[None] - y[e, None]  # (num_evaluated, num_objects, num_steps)
    lower = jnp.sqrt(dx * dx + dy * dy) * interaction.BOUND_SCALE - (
        (reach[e, None] + reach[None]) + interaction.BOUND_MARGIN
    )
    self_pair = jnp.eye(num_evaluated, x.shape[0], dtype=bool)[..., None]
    # NaN and the self pair never guide the search; -0 ranks as +0 (the loop's order).
    lower = jnp.where(jnp.isnan(lower) | self_pair, jnp.inf, jnp.where(lower == 0, _F(0), lower))
    lower = jnp.moveaxis(lower, 1, -1)  # (num_evaluated, num_steps, num_objects)
    lowest, pick = _lowest_k(lower, k + 1)
    # The candidates' outlines and radii in one gather of rows (one per box and step), not one per value.
    num_objects, num_steps = x.shape
    boxes = jnp.stack(outlines + (radius,), axis=-1).reshape(num_objects * num_steps, len(outlines) + 1)
    rows = pick[..., :k] * num_steps + jnp.arange(num_steps)[None, :, None]
    gathered = jnp.take(boxes, rows, axis=0)  # (evaluated, steps, k, values)
    own = tuple(jnp.broadcast_to(v[e, :, None], rows.shape) for v in outlines)
    d = interaction.outline_distance(
        own, tuple(jnp.moveaxis(gathered[..., :-1], -1, 0)), radius[e, :, None], gathered[..., -1]
    )
    guess = d[..., 0]
    guess = jnp.where(
        (guess < interaction.EXTREMELY_LARGE_DISTANCE) | jnp.isnan(guess), guess, interaction.EXTREMELY_LARGE_DISTANCE
    )
    threshold = guess + interaction.BOUND_MARGIN
    searched = (lowest[..., :k] <= threshold[..., None]).at[..., 0].set(True) & (lowest[..., :k] < jnp.inf)
    d = nan_spreading_min(jnp.where(searched, d.at[..., 0].set(guess), jnp.inf), axis=-1)
    found = lowest[..., 0] < jnp.inf
    distance = jnp.where(
        found, jnp.minimum(d, interaction.EXTREMELY_LARGE_DISTANCE), interaction.EXTREMELY_LARGE_DISTANCE
    )
    exhaustive = (interaction.exhaustive_boxes(x, y, length, width, cos_h, sin_h) & valid).any(axis=0)
    settled = (~(lowest[..., k] <= threshold) | jnp.isnan(threshold)) & ~exhaustive[None]
    return distance, settled | ~valid[e]


def nearest_object_distance(
    x: Any, y: Any, length: Any, width: Any, cos_h: Any, sin_h: Any, valid: Any, num_evaluated: int
) -> Any:
    """Dense `interaction.distance_to_nearest_object` for one sample.

    Each (evaluated object, step) evaluates its `NEAREST_OBJECT_CANDIDATES` boxes of lowest bound
    (`_nearest_object_candidates`); the rows the bound does not settle (crowds, NaN or huge boxes)
    are compacted and searched against every box in a `while_loop`. The result equals the
    official all-pairs minimum bit for bit (the minimum of the same pair distances).

    Args:
      x, y, length, width, cos_h, sin_h: float32 `(num_objects, num_steps)`.
      valid: bool `(num_objects, num_steps)`.
    Returns:
      float32 `(num_evaluated, num_steps)`; 1e10 where nothing valid is near.
    """
    num_objects, num_steps = x.shape
    radius = interaction.corner_radius(length, width)
    # Every box's outline once, then gathered for the pairs evaluated.
    outlines = interaction.box_outlines(x, y, length - _F(2) * radius, width - _F(2) * radius, cos_h, sin_h)
    rows = jnp.repeat(jnp.arange(num_evaluated), num_steps)
    steps = jnp.tile(jnp.arange(num_steps), num_evaluated)
    # As many boxes as candidates, or traced for gradients (reverse mode cannot pass the fallback's
    # `while_loop`): all pairs at once.
    if num_objects <= NEAREST_OBJECT_CANDIDATES + 1 or in_differentiable(jnp):
        return _nearest_object_all_pairs(outlines, radius, valid, rows, steps).reshape(num_evaluated, num_steps)
    distance, settled = _nearest_object_candidates(
        x, y, length, width, cos_h, sin_h, outlines, radius, valid, num_evaluated
    )
    every_box = lambda r: _nearest_object_all_pairs(outlines, radius, valid, rows[r], steps[r])  # noqa: E731
    distance = fill_rows(distance.reshape(-1), ~settled.reshape(-1), NEAREST_OBJECT_FALLBACK_CHUNK, every_box)
    return distance.reshape(num_evaluated, num_steps)


def time_to_collision(
    x: Any,
    y: Any,
    length: Any,
    width: Any,
    heading: Any,
    speed: Any,
    valid: Any,
    *,
    ego_tail: Any,
    pair_tail: Any,
    num_evaluated: int,
) -> Any:
    """Dense `following.time_to_collision` for one sample, object-major: the pairs are
    `(num_evaluated, num_objects, num_steps)`, in the trajectories' own layout (no transposed copy of
    them), with the official kernels' elementwise arithmetic and the same nearest followed object.

    Args:
      x, y, length, width, heading, speed: float32 `(num_objects, num_steps)`, the evaluated steps.
      valid: bool `(num_objects, num_steps)`.
      ego_tail: bool `(num_evaluated, 1, num_steps)`, pair_tail: bool
        `(num_evaluated, num_objects, num_steps)`: the official ops' trailing
        packets, from the real (unpadded) shapes.
    Returns:
      float32 `(num_evaluated, num_steps)`.
    """
    e = slice(0, num_evaluated)
    ego_sin, ego_cos = sincos32(-heading[e, None], ego_tail)
    ahead, beside, yaw_diff = following.frame_offsets(
        x[None],
        y[None],
        x[e, None],
        y[e, None],
        ego_cos,
        ego_sin,
        length[e, None],
        width[e, None],
        heading[None],
        heading[e, None],
    )
    pairs = following.FollowedPairs(ahead, beside, yaw_diff, pair_tail, length[None], width[None], valid[None])
    masked = following.followed_gaps(pairs)
    # The nearest followed object, as `following.all_objects_time_to_collision` picks it along its objects.
    if in_differentiable(jnp):  # gradients through the gap: JAX differentiates no custom reduction
        nearest = strict_argmin(masked, axis=1)
        gap = jnp.take_along_axis(masked, nearest[:, None], axis=1)[:, 0]
    else:
        nearest, gap = _strict_argmin_and_value(masked)
    closing = speed[e] - jnp.take_along_axis(speed, nearest, axis=0)
    return following.capped_time_to_collision(gap, closing)


def _strict_argmin_and_value(values: Any) -> Any:
    """`spatial.strict_argmin` along axis 1 of `values` `(batch, num_values, ...)` and the value it picks, in one
    reduction: the pairs are never stored, only reduced as they are computed. int32 and float32 `(batch, ...)`."""
    n = values.shape[1]
    index = lax.broadcasted_iota(jnp.int32, values.shape, 1)
    candidates = jnp.where(jnp.isnan(values), _F(np.inf), values)
    init = (_F(np.inf), np.int32(n), _F(0), np.int32(n), _F(0))
    # (first lowest candidate, its index, its value; the first index, its value): the first is strict_argmin's
    # pick when its candidate is below float32's largest finite value, else index 0 is.
    lowest, pick, picked, _, first = lax.reduce(
        (candidates, index, values, index, values), init, _first_lowest_and_first, (1,)
    )
    below = lowest < np.finfo(np.float32).max
    return jnp.where(below, pick, 0), jnp.where(below, picked, first)


def _first_lowest_and_first(a: Any, b: Any) -> Any:
    """`_strict_argmin_and_value`'s combiner: the lower candidate (the lower index on ties) with its value,
    and the lower index with its value (comparisons and selects only: the exact mode keeps it as it is)."""
    take = lax.lt(b[0], a[0]) | (lax.eq(b[0], a[0]) & lax.lt(b[1], a[1]))
    first = lax.lt(b[3], a[3])
    return (
        lax.select(take, b[0], a[0]),
        lax.select(take, b[1], a[1]),
        lax.select(take, b[2], a[2]),
        lax.select(first, b[3], a[3]),
        lax.select(first, b[4], a[4]),
    )


def nearest_lane_segment(xy: Any, lane_start: Any, lane_delta: Any, lane_valid: Any) -> Any:
    """Dense `traffic_lights.nearest_lane_segment`: index into the given segments.

    Args:
      xy: float32 `(num_points, 2)`.
      lane_start, lane_delta: float32 `(num_segments, 2)`; lane_valid: bool `(num_segments,)`.
    Returns:
      int `(num_points,)`.
    """

    def nearest(q: Any) -> Any:
        d = traffic_lights.lane_measure(q[:, None, :], lane_start[None], lane_delta[None])
        return jnp.argmin(jnp.where(lane_valid[None], d, jnp.inf), axis=-1)

    return chunked(nearest, xy, rows_per_chunk(lane_start.shape[0]))


# Red-light crossings whose lane is looked up at once; more are handled in further rounds.
LANE_SEARCH_CHUNK = 64


def red_light_violation(xy: Any, valid: Any, m: Any) -> Any:
    """Dense `traffic_lights.red_light_violation` for one scene, without leaving the device.

    The lane search runs only on the points that crossed a stopped signal's
    line (rare): they are compacted to the front and looked up
    `LANE_SEARCH_CHUNK` at a time in a `while_loop`, so the work follows the
    number of crossings, not the number of points.

    Args:
      xy: float32 `(..., num_objects, num_steps, 2)`.
      valid: bool `(..., num_objects, num_steps)`.
      m: padded map arrays: stop_start, stop_delta, stop_point float32
        `(num_steps, num_signals, 2)`, stopping bool `(num_steps, num_signals)`,
        signal_lane_id int `(num_signals,)`; lane_start, lane_delta float32
        `(num_segments, 2)`, lane_valid bool and lane_id int `(num_segments,)`.
    Returns:
      bool `(..., num_objects, num_steps)`.
    """
    suspect = traffic_lights.stop_line_crossings(
        xy, valid, m["stop_start"], m["stop_delta"], m["stop_point"], m["stopping"]
    )
    flat_suspect = suspect.reshape(-1, suspect.shape[-1])
    on_lane = on_signal_lane(xy.reshape(-1, 2), flat_suspect.any(axis=-1), m)
    return (flat_suspect & on_lane).any(axis=-1).reshape(suspect.shape[:-1])


def on_signal_lane(points: Any, needed: Any, m: Any, chunk: int = LANE_SEARCH_CHUNK) -> Any:
    """Whether each point's nearest lane is each signal's lane: bool `(num_points, num_signals)`, the lane
    searched only for the `needed` points (False elsewhere), `chunk` points per round (`fill_rows`).

    Args:
      points: float32 `(num_points, 2)`; needed: bool `(num_points,)`.
      m: the padded map arrays of `red_light_violation`.
    """

    def lane_of(rows: Any) -> Any:
        return m["lane_id"][nearest_lane_segment(points[rows], m["lane_start"], m["lane_delta"], m["lane_valid"])]

    lane_of_point = fill_rows(jnp.full(needed.shape, -1, m["lane_id"].dtype), needed, chunk, lane_of)
    return lane_of_point[:, None] == m["signal_lane_id"][None, :]


def _nan_spreading_max_last(a: Any) -> Any:
    """`xp.nan_spreading_max(a, axis=-1)` as one reduction: the maximum and whether a NaN is met."""
    top, nan = lax.reduce((a, jnp.isnan(a)), (_F(-np.inf), False), _max_and_any, (a.ndim - 1,))
    return jnp.where(nan, _F(np.nan), top)


def _max_and_any(a: Any, b: Any) -> Any:
    return lax.max(a[0], b[0]), lax.bitwise_or(a[1], b[1])


class DenseSearch:
    """The dense (JAX) search strategy of `metric_features.per_step_features` (a `SearchStrategy`).

    Every candidate pair of padded, masked arrays is evaluated and minima are
    picked with `argmin` (lowest index wins ties, as in `PrunedSearch`); the
    features are bit-identical to the pruned search's. `m` holds the padded
    map arrays of one scene (see `signed_distance_to_road_edge` and
    `red_light_violation`).
    """

    def __init__(self, m: dict) -> None:
        self.m = m

    def nearest_object(
        self, x: Any, y: Any, length: Any, width: Any, cos_h: Any, sin_h: Any, valid: Any, num_evaluated: int
    ) -> Any:
        boxes = (x, y, length, width, cos_h, sin_h, valid)

        def per_sample(sample: Any) -> Any:
            # The sample read in place: mapped over as `lax.map`'s operands, arrays with a scene axis
            # before the samples (under `vmap`) would be copied with that axis moved behind them first.
            x, y, length, width, cos_h, sin_h, valid = (
                lax.dynamic_index_in_dim(a, sample, keepdims=False) for a in boxes
            )
            return nearest_object_distance(x, y, length, width, cos_h, sin_h, valid, num_evaluated)

        return lax.map(per_sample, jnp.arange(x.shape[0]))

    def time_to_collision(self, inputs: TimeToCollisionInputs) -> Any:
        i = inputs
        # The tails (official shapes, step-major) object-major as the pairs: one scene's, not per sample.
        per_sample = functools.partial(
            time_to_collision,
            ego_tail=jnp.transpose(jnp.asarray(i.ego_tail), (1, 2, 0)),
            pair_tail=jnp.transpose(jnp.asarray(i.pair_tail), (1, 2, 0)),
            num_evaluated=i.num_evaluated,
        )
        at = lambda a: a[..., i.steps]  # noqa: E731
        return jax.vmap(per_sample)(*map(at, (i.x, i.y, i.length, i.width, i.heading, i.speed, i.valid)))

    def road_edge_distance(
        self, x: Any, y: Any, bottom: Any, length: Any, width: Any, cos_h: Any, sin_h: Any, valid: Any
    ) -> Any:
        corners = box_geometry.box_bottom_corners(x, y, bottom, length, width, cos_h, sin_h)
        needed = jnp.broadcast_to(valid[..., None], corners.shape[:-1]).reshape(-1)
        edge = signed_distance_to_road_edge(corners.reshape(-1, 3), self.m, needed)
        edge = edge.reshape(corners.shape[:-1])
        # The corners' maximum in one pass (its two reductions in one: the corners' distances never stored).
        edge = nan_spreading_max(edge, axis=-1) if in_differentiable(jnp) else _nan_spreading_max_last(edge)
        return jnp.where(valid, edge, -road_edge.EXTREMELY_LARGE_DISTANCE)

    def red_light_violation(self, x: Any, y: Any, valid: Any) -> Any:
        return red_light_violation(jnp.stack([x, y], axis=-1), valid, self.m)
