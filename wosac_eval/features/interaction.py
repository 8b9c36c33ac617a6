"""Interactive features: distance to the nearest object and collisions (time to collision: `following`).

Objects are laid out with the evaluated objects first (`num_evaluated` of
them), followed by every other sim agent. Interactions are computed for the
evaluated objects against all objects: `(num_evaluated x num_objects)` pairs.
"""

from __future__ import annotations

import contextlib
import contextvars
from typing import Any

import numba
import numpy as np

from wosac_eval.features.box_geometry import box_outline, minkowski_vertices, octagon_signed_distance
from wosac_eval.features.compiled import cached_loop, compiled
from wosac_eval.features.spatial import nonzero
from wosac_eval.features.xp import array_namespace, errstate

_F = np.float32
EXTREMELY_LARGE_DISTANCE = _F(1e10)
COLLISION_DISTANCE_THRESHOLD = 0.0
CORNER_ROUNDING_FACTOR = 0.7
# Set by `corner_rounding()`: the metrics always round by CORNER_ROUNDING_FACTOR, the official function by its argument.
_ROUNDING = contextvars.ContextVar("wosac_eval_corner_rounding", default=CORNER_ROUNDING_FACTOR)


@contextlib.contextmanager
def corner_rounding(factor: float) -> Any:
    """Boxes' corners rounded by `factor` (0: sharp rectangles, 1: capsules) instead of 0.7 inside this block.

    The official `compute_distance_to_nearest_object` takes the factor as an argument; the metrics use
    0.7. A rounded box lies within its box for a factor in [0, 1], which the nearest-object search's
    bounds rely on: other factors are refused.
    """
    if not 0 <= factor <= 1:
        raise ValueError(f"the corner rounding factor must be between 0 and 1, got {factor}")
    token = _ROUNDING.set(factor)
    try:
        yield
    finally:
        _ROUNDING.reset(token)


def corner_radius(length: Any, width: Any) -> Any:
    """Radius of the rounded corners: `0.7 * min(length, width) / 2` (0.7: or `corner_rounding`'s), float32 `(...)`."""
    return array_namespace(length, width).minimum(length, width) * _F(_ROUNDING.get()) / _F(2)


def box_outlines(x: Any, y: Any, core_length: Any, core_width: Any, cos_h: Any, sin_h: Any) -> Any:
    """`box_geometry.box_outline` of rounded boxes' cores, computed once per box (an `ops` kernel)."""
    return box_outline(x, y, core_length, core_width, cos_h, sin_h)


def outline_distance(a: Any, b: Any, radius_a: Any, radius_b: Any) -> Any:
    """Signed distance between rounded boxes from their cores' outlines and corner radii (an `ops` kernel).

    A box of zero size (a logged placeholder state, scored as is in scenario
    gen) has no edges: its edge directions are NaN, as officially.
    """
    return (octagon_signed_distance(minkowski_vertices(a, b)) - radius_a) - radius_b


def rounded_box_distance(a: Any, b: Any) -> Any:
    """Signed distance between rounded boxes given as (x, y, core_length, core_width, cos, sin, radius).

    Args:
      a, b: tuples of float32 values, all broadcast to one shape `(...)` (numpy, JAX or scalars).
    Returns:
      float32 `(...)`.
    """
    return outline_distance(
        box_outlines(a[0], a[1], a[2], a[3], a[4], a[5]), box_outlines(b[0], b[1], b[2], b[3], b[4], b[5]), a[6], b[6]
    )


def box_pair_distance(
    x_a: Any,
    y_a: Any,
    core_length_a: Any,
    core_width_a: Any,
    cos_a: Any,
    sin_a: Any,
    radius_a: Any,
    x_b: Any,
    y_b: Any,
    core_length_b: Any,
    core_width_b: Any,
    cos_b: Any,
    sin_b: Any,
    radius_b: Any,
) -> Any:
    """`rounded_box_distance` of boxes given value by value (an `ops` kernel over pairs)."""
    return rounded_box_distance(
        (x_a, y_a, core_length_a, core_width_a, cos_a, sin_a, radius_a),
        (x_b, y_b, core_length_b, core_width_b, cos_b, sin_b, radius_b),
    )


_box_pair_distance = compiled(box_pair_distance)
# The nearest-object search evaluates its first guess for every box (about 1.1 evaluations per box in
# all): that call is compiled inline, which makes it about a fifth faster and the first compilation
# about 8 s longer (once: numba caches it); the other calls are calls.
_box_pair_distance_inline = compiled(box_pair_distance, True)


@numba.njit
def _bounds_of_step(step_x: Any, step_y: Any, step_reach: Any, e: Any, lower: Any) -> None:
    """Lower bounds of the distance from box e to each box of one step (`lower`, in place): centre
    distance less both bounding radii, with float32 margins; +inf for e itself and unsearched boxes.
    A NaN bound is +inf and -0 is +0 (neither changes what the bounds select, see `_lowest`)."""
    for o in range(step_x.shape[0]):  # branch-free: the compiler vectorises it
        dx, dy = step_x[o] - step_x[e], step_y[o] - step_y[e]
        bound = np.sqrt(dx * dx + dy * dy) * BOUND_SCALE - ((step_reach[e] + step_reach[o]) + BOUND_MARGIN)
        bound = bound + np.float32(0)
        lower[o] = bound if bound == bound else np.float32(np.inf)
    lower[e] = np.inf  # not against itself


_INF_BITS, _FLIP = np.int32(0x7F800000), np.int32(0x7FFFFFFF)


@numba.njit
def _lowest(lower: Any) -> Any:
    """The first index of the lowest of `lower` (from `_bounds_of_step`: no NaN, no -0), -1 if none is
    below +inf: what a scan keeping the first strict minimum picks. The lowest is found by an integer
    minimum over the values' bits, ordered as the floats (negative ones flipped), which the compiler
    vectorises (a float minimum it cannot), then its first index."""
    bits = lower.view(np.int32)
    lowest = _INF_BITS
    for o in range(bits.shape[0]):
        i = bits[o]
        lowest = min(lowest, i if i >= 0 else i ^ _FLIP)
    if lowest == _INF_BITS:
        return -1
    for o in range(bits.shape[0]):
        i = bits[o]
        if (i if i >= 0 else i ^ _FLIP) == lowest:
            return o
    return -1


# fmt: off
# (to `fmt: on`: the loop's ten parameters on two lines; one a line would take it past the 80-line cap)
@cached_loop
def _nearest_object_search(x: Any, y: Any, core_length: Any, core_width: Any, cos_h: Any, sin_h: Any, radius: Any,
                           reach: Any, apart: Any, num_evaluated: int) -> Any:
    """The nearest valid other box of each evaluated box, over the boxes not set `apart`.

    The distance between two rounded boxes is at least the distance between
    their centres less their bounding radii (`reach`, -inf for an invalid box),
    with float32 margins: the most promising box (lowest bound) is evaluated
    exactly first, then every box whose bound does not exclude it.

    Args:
      x, y, core_length, core_width, cos_h, sin_h, radius, reach: float32
        `(batch, num_objects, num_steps)`; apart: bool, the same shape.
    Returns:
      (float32 `(batch, num_evaluated, num_steps)`: 1e10 where nothing valid is near; the number
      of pairs evaluated exactly).
    """
    batch, num_objects, num_steps = x.shape
    out = np.full((batch, num_evaluated, num_steps), EXTREMELY_LARGE_DISTANCE, np.float32)
    evaluated = 0
    lower = np.empty(num_objects, np.float32)
    # One step's boxes, contiguous (reach -inf for boxes not searched here).
    step = np.empty((7, num_objects), np.float32)  # x, y, core length, core width, cos, sin, radius
    step_reach = np.empty(num_objects, np.float32)
    for b in range(batch):
        for t in range(num_steps):
            for o in range(num_objects):
                step[0, o], step[1, o], step[2, o] = x[b, o, t], y[b, o, t], core_length[b, o, t]
                step[3, o], step[4, o], step[5, o] = core_width[b, o, t], cos_h[b, o, t], sin_h[b, o, t]
                step[6, o] = radius[b, o, t]
                step_reach[o] = -np.inf if apart[b, o, t] else reach[b, o, t]
            for e in range(num_evaluated):
                if not step_reach[e] > -np.inf:
                    continue
                _bounds_of_step(step[0], step[1], step_reach, e, lower)
                guess = _lowest(lower)
                if guess < 0:
                    continue
                # The guess, then every other box whose bound its distance (capped at 1e10) does not exclude.
                d = _box_pair_distance_inline(
                    step[0, e],
                    step[1, e],
                    step[2, e],
                    step[3, e],
                    step[4, e],
                    step[5, e],
                    step[6, e],
                    step[0, guess],
                    step[1, guess],
                    step[2, guess],
                    step[3, guess],
                    step[4, guess],
                    step[5, guess],
                    step[6, guess],
                )
                d = d if (d < EXTREMELY_LARGE_DISTANCE) | (d != d) else EXTREMELY_LARGE_DISTANCE
                threshold = d + BOUND_MARGIN
                evaluated += 1
                for o in range(num_objects):
                    if o != guess and lower[o] <= threshold:
                        pair = _box_pair_distance(
                            step[0, e],
                            step[1, e],
                            step[2, e],
                            step[3, e],
                            step[4, e],
                            step[5, e],
                            step[6, e],
                            step[0, o],
                            step[1, o],
                            step[2, o],
                            step[3, o],
                            step[4, o],
                            step[5, o],
                            step[6, o],
                        )
                        evaluated += 1
                        d = d if (d < pair) | (d != d) else pair  # numpy's minimum: NaN passes on
                out[b, e, t] = d
    return out, evaluated
# fmt: on


BOUND_SCALE, BOUND_MARGIN = _F(1 - 1e-5), _F(1e-3)  # the centre distance's float32 rounding, with margin


# Pairs (samples x evaluated x steps x objects) processed at once by `_by_samples`: bounds the
# working memory of the vectorised passes (a few arrays of this size).
PAIRS_PER_CHUNK = 1 << 21


def _sample_chunks(num_samples: int, pairs_per_sample: int) -> Any:
    """Slices of the samples axis holding at most `PAIRS_PER_CHUNK` pairs (at least one sample)."""
    step = max(1, PAIRS_PER_CHUNK // max(1, pairs_per_sample))
    return [slice(i, i + step) for i in range(0, max(num_samples, 1), step)]


def _by_samples(fn: Any, arrays: Any, num_evaluated: int, **kwargs: Any) -> Any:
    """Runs `fn` over chunks of the flattened leading (samples) axes and joins the results."""
    lead, (num_objects, num_steps) = arrays[0].shape[:-2], arrays[0].shape[-2:]
    flat = [np.reshape(a, (-1,) + a.shape[-2:]) for a in arrays]
    chunks = _sample_chunks(flat[0].shape[0], num_evaluated * num_objects * num_steps)
    if len(chunks) == 1:
        out = fn(*flat, num_evaluated, **kwargs)
    else:
        out = np.concatenate([fn(*(a[c] for a in flat), num_evaluated, **kwargs) for c in chunks])
    return out.reshape(*lead, *out.shape[1:])


def distance_to_nearest_object(
    x: np.ndarray,
    y: np.ndarray,
    length: np.ndarray,
    width: np.ndarray,
    cos_h: np.ndarray,
    sin_h: np.ndarray,
    valid: np.ndarray,
    num_evaluated: int,
    counts: dict | None = None,
) -> np.ndarray:
    """Signed distance between rounded boxes, to the nearest other valid object.

    Boxes are rectangles whose corners are rounded by a radius of
    `0.7 * min(length, width) / 2`: the distance between two such shapes is the
    distance between their shrunk rectangular cores minus both radii.

    Only pairs that can be nearest are evaluated exactly (`_nearest_object_search`,
    compiled); the result equals the all-pairs minimum bit for bit.

    Args:
      x, y, length, width, cos_h, sin_h: float32 `(..., num_objects, num_steps)`.
      valid: bool `(..., num_objects, num_steps)`.
      num_evaluated: the first `num_evaluated` objects are scored.
      counts: optional dict that gets the work done: "pairs evaluated" (exact box distances).
    Returns:
      float32 `(..., num_evaluated, num_steps)`; 1e10 where the object is
      invalid or no other valid object exists.
    """
    work = {"pairs evaluated": 0}
    out = _by_samples(_nearest_object_chunk, (x, y, length, width, cos_h, sin_h, valid), num_evaluated, work=work)
    if counts is not None:
        counts.update(work)
    return out


def _nearest_object_chunk(
    x: Any, y: Any, length: Any, width: Any, cos_h: Any, sin_h: Any, valid: Any, num_evaluated: int, work: dict
) -> Any:
    e = num_evaluated
    radius = corner_radius(length, width)
    reach = bounding_reach(length, width, valid)
    # The valid pairs of these boxes are all evaluated exactly below, the self pair too.
    exhaustive = exhaustive_boxes(x, y, length, width, cos_h, sin_h)
    c = lambda a: np.ascontiguousarray(a, _F)  # noqa: E731
    distance, evaluated = _nearest_object_search(
        c(x),
        c(y),
        c(length - _F(2) * radius),
        c(width - _F(2) * radius),
        c(cos_h),
        c(sin_h),
        c(radius),
        reach,
        np.ascontiguousarray(exhaustive),
        e,
    )
    work["pairs evaluated"] += evaluated
    if exhaustive.any():
        pair = (exhaustive[:, :e, None] | exhaustive[:, None]) & valid[:, :e, None] & valid[:, None]
        ub, ue, uo, us = nonzero(pair)

        def box(i: Any) -> Any:
            return (
                x[ub, i, us],
                y[ub, i, us],
                length[ub, i, us] - _F(2) * radius[ub, i, us],
                width[ub, i, us] - _F(2) * radius[ub, i, us],
                cos_h[ub, i, us],
                sin_h[ub, i, us],
                radius[ub, i, us],
            )

        d = rounded_box_distance(box(ue), box(uo)).astype(_F)
        d = np.where(ue == uo, d + EXTREMELY_LARGE_DISTANCE, d)
        np.minimum.at(distance, (ub, ue, us), d)
        work["pairs evaluated"] += len(d)
    return distance


def bounding_reach(length: Any, width: Any, valid: Any) -> Any:
    """The bounding radius of each valid box (half its diagonal), -inf for an invalid one: float32 `(...)`.

    The nearest-object bound of a pair is their centres' distance less both reaches
    (`BOUND_SCALE`, `BOUND_MARGIN`); an invalid box is never within it.
    """
    xp = array_namespace(length)
    return xp.where(valid, _F(0.5) * xp.hypot(length, width), _F(-np.inf)).astype(_F)


def exhaustive_boxes(x: Any, y: Any, length: Any, width: Any, cos_h: Any, sin_h: Any) -> Any:
    """Boxes whose valid pairs the nearest-object search evaluates all, the self pair too: bool `(...)`.

    A box with a NaN, an infinity or a huge value (`unbounded_boxes`) has no usable bound, and its
    distances may be NaN, which the official all-pairs minimum passes on; the self pair (officially
    offset by 1e10, not left out) counts for NaN, and for boxes over 512 m wide, whose self distance
    + 1e10 rounds below 1e10.
    """
    xp = array_namespace(length)
    return unbounded_boxes(x, y, length, width, cos_h, sin_h) | (xp.minimum(length, width) > _F(256))


# Beyond this magnitude (metres) the float32 margins of the distance bounds no longer hold.
BOUNDED_MAGNITUDE = _F(1e6)


def unbounded_boxes(*values: Any) -> Any:
    """Boxes with a value that is NaN, infinite or beyond `BOUNDED_MAGNITUDE`: bool, the values' shape `(...)`.

    The pruned searches skip pairs by bounds that only hold for finite,
    moderate values; these boxes are searched exhaustively instead.
    """
    xp = array_namespace(values[0])
    out = xp.zeros(values[0].shape, dtype=bool)
    for value in values:
        with errstate(xp, invalid="ignore"):
            out = out | ~(xp.abs(value) <= BOUNDED_MAGNITUDE)
    return out
