"""Interactive features: distance to the nearest object, collisions, time to collision.

Objects are laid out with the evaluated objects first (`num_evaluated` of
them), followed by every other sim agent. Interactions are computed for the
evaluated objects against all objects: `(num_evaluated x num_objects)` pairs.
"""
from __future__ import annotations

import math

import numpy as np

from wosac_eval.features import box_geometry
from wosac_eval.features.float32_math import packet_tail, sincos32
from wosac_eval.features.kinematics import linear_speed
from wosac_eval.features.spatial import first_minimum, nonzero, strict_argmin
from wosac_eval.features.xp import array_namespace, divide, errstate, is_numpy

_F = np.float32
EXTREMELY_LARGE_DISTANCE = _F(1e10)
COLLISION_DISTANCE_THRESHOLD = 0.0
CORNER_ROUNDING_FACTOR = 0.7
MAX_HEADING_DIFF = _F(math.radians(75.0))
MAX_HEADING_DIFF_FOR_SMALL_OVERLAP = _F(math.radians(10.0))
SMALL_OVERLAP_THRESHOLD = _F(0.5)
MAXIMUM_TIME_TO_COLLISION = _F(5.0)


def corner_radius(length, width):
    """Radius of the rounded corners: `0.7 * min(length, width) / 2`, float32 `(...)`."""
    return array_namespace(length, width).minimum(length, width) * _F(CORNER_ROUNDING_FACTOR) / _F(2)


def box_outlines(x, y, core_length, core_width, cos_h, sin_h):
    """`box_geometry.outline` of rounded boxes' cores, float32 arrays `(...)` in, computed once per box."""
    return box_geometry.outline(*box_geometry.box_corners_xy(x, y, core_length, core_width, cos_h, sin_h))


def outline_distance(a, b, radius_a, radius_b):
    """Signed distance between rounded boxes from their cores' outlines and corner radii (broadcast).

    A box of zero size (a logged placeholder state, scored as is in scenario
    gen) has no edges: its distances are NaN, as officially.
    """
    with errstate(array_namespace(a[0]), invalid="ignore", divide="ignore"):
        core = box_geometry.origin_signed_distance(*box_geometry.minkowski_difference_of(a, b))
    return (core - radius_a) - radius_b


def rounded_box_distance(a, b):
    """Signed distance between rounded boxes given as (x, y, core_length, core_width, cos, sin, radius).

    Args:
      a, b: tuples of float32 arrays, all broadcast to one shape `(...)` (numpy or JAX).
    Returns:
      float32 `(...)`.
    """
    return outline_distance(box_outlines(*a[:6]), box_outlines(*b[:6]), a[6], b[6])


class _Outlines:
    """`box_outlines` of flat boxes, each computed once, on first use.

    With few evaluated objects (sim agents) only a small share of the boxes
    ever takes part in a pair; with every object evaluated (scenario gen)
    nearly all do, and each box is still outlined once.
    """

    def __init__(self, x, y, core_length, core_width, cos_h, sin_h, eager: bool = False):
        self.boxes = (x, y, core_length, core_width, cos_h, sin_h)
        self.done = np.full(len(x), eager)
        self.values: tuple | None = box_outlines(*self.boxes) if eager else None

    def take(self, idx: np.ndarray) -> tuple:
        todo = np.flatnonzero(np.bincount(idx[~self.done[idx]], minlength=len(self.done)))
        if todo.size:
            fresh = box_outlines(*(np.take(b, todo) for b in self.boxes))
            if self.values is None:
                self.values = tuple(np.empty((len(self.done),) + v.shape[1:], v.dtype) for v in fresh)
            for store, v in zip(self.values, fresh):
                store[todo] = v
            self.done[todo] = True
        return tuple(np.take(v, idx, axis=0) for v in self.values)


def _pair_distance(outlines: _Outlines, radius, eval_idx, other_idx):
    """Exact float32 signed distance between rounded boxes for the given pairs.

    Args:
      outlines: the boxes' outlines (`_Outlines`, flat).
      radius: float32 `(num_boxes,)` corner radii.
      eval_idx, other_idx: int `(num_pairs,)` indices into the boxes.
    """
    return outline_distance(outlines.take(eval_idx), outlines.take(other_idx), radius[eval_idx], radius[other_idx])


# Pairs (samples x evaluated x steps x objects) processed at once: bounds the
# working memory of the dense bounds (a few float32 arrays of this size).
PAIRS_PER_CHUNK = 1 << 21


def _sample_chunks(num_samples: int, pairs_per_sample: int):
    """Slices of the samples axis holding at most `PAIRS_PER_CHUNK` pairs (at least one sample)."""
    step = max(1, PAIRS_PER_CHUNK // max(1, pairs_per_sample))
    return [slice(i, i + step) for i in range(0, max(num_samples, 1), step)]


def _by_samples(fn, arrays, num_evaluated: int, **kwargs):
    """Runs `fn` over chunks of the flattened leading (samples) axes and joins the results."""
    lead, (num_objects, num_steps) = arrays[0].shape[:-2], arrays[0].shape[-2:]
    flat = [np.reshape(a, (-1,) + a.shape[-2:]) for a in arrays]
    chunks = _sample_chunks(flat[0].shape[0], num_evaluated * num_objects * num_steps)
    if len(chunks) == 1:
        out = fn(*flat, num_evaluated, **kwargs)
    else:
        out = np.concatenate([fn(*(a[c] for a in flat), num_evaluated, **kwargs) for c in chunks])
    return out.reshape(*lead, *out.shape[1:])


def distance_to_nearest_object(x, y, length, width, cos_h, sin_h, valid, num_evaluated: int):
    """Signed distance between rounded boxes, to the nearest other valid object.

    Boxes are rectangles whose corners are rounded by a radius of
    `0.7 * min(length, width) / 2`: the distance between two such shapes is the
    distance between their shrunk rectangular cores minus both radii.

    Only pairs that can be nearest are evaluated exactly: the distance between
    two shapes is at least the distance between their centres minus their
    bounding radii, so after evaluating the most promising object (lowest
    bound), any pair whose lower bound exceeds the distance found is skipped.
    The result equals the all-pairs minimum bit for bit.

    Args:
      x, y, length, width, cos_h, sin_h: float32 `(..., num_objects, num_steps)`.
      valid: bool `(..., num_objects, num_steps)`.
      num_evaluated: the first `num_evaluated` objects are scored.
    Returns:
      float32 `(..., num_evaluated, num_steps)`; 1e10 where the object is
      invalid or no other valid object exists.
    """
    return _by_samples(_nearest_object_chunk, (x, y, length, width, cos_h, sin_h, valid), num_evaluated)


def _nearest_object_chunk(x, y, length, width, cos_h, sin_h, valid, num_evaluated: int):
    lead, (num_objects, num_steps) = x.shape[:-2], x.shape[-2:]
    e = num_evaluated
    radius = corner_radius(length, width)
    flat = lambda a: np.ascontiguousarray(a).reshape(-1)
    # Each box's outline once, when a pair first needs it (all at once when most objects are
    # evaluated: most boxes will be); pairs then only gather.
    outlines = _Outlines(flat(x), flat(y), flat(length - _F(2) * radius), flat(width - _F(2) * radius),
                         flat(cos_h), flat(sin_h), eager=2 * e >= num_objects)
    radii = flat(radius)
    # Step-major copies (batch, step, object) so that objects are the last axis.
    step_major = lambda a: np.ascontiguousarray(np.swapaxes(a.reshape(-1, num_objects, num_steps), 1, 2))
    xt, yt = step_major(x), step_major(y)
    # Bounding radii; invalid boxes get -inf so that their bounds become +inf.
    reach = np.where(step_major(valid), step_major(_F(0.5) * np.hypot(length, width)), -np.inf).astype(_F)
    # Lower bounds (batch, eval, step, object), computed in place:
    # centre distance * (1 - 1e-5) - both radii - 1e-3 (float32 rounding margin).
    lower = xt[:, None] - np.swapaxes(xt[:, :, :e], 1, 2)[..., None]
    lower *= lower
    dy = yt[:, None] - np.swapaxes(yt[:, :, :e], 1, 2)[..., None]
    dy *= dy
    lower += dy
    np.sqrt(lower, out=lower)
    lower *= _F(1 - 1e-5)
    reach_sum = np.swapaxes(reach[:, :, :e], 1, 2)[..., None] + reach[:, None]
    reach_sum += _F(1e-3)
    lower -= reach_sum
    evaluated = np.arange(e)
    lower[:, evaluated, :, evaluated] = np.inf  # not against itself
    batch = lower.shape[0]
    box_of = lambda bb, obj, step: (bb * num_objects + obj) * num_steps + step
    # First guess: the object with the lowest bound, evaluated exactly.
    guess = np.argmin(lower, axis=-1)
    gb, ge, gs = nonzero(np.isfinite(np.take_along_axis(lower, guess[..., None], axis=-1)[..., 0]))
    go = guess[gb, ge, gs]
    distance = np.full((batch, e, num_steps), EXTREMELY_LARGE_DISTANCE, dtype=_F)
    if gb.size:
        guess_d = _pair_distance(outlines, radii, box_of(gb, ge, gs), box_of(gb, go, gs)).astype(_F)
        distance[gb, ge, gs] = np.minimum(guess_d, EXTREMELY_LARGE_DISTANCE)
        # Then every other pair whose bound does not exclude it.
        lower[gb, ge, gs, go] = np.inf
        cb, ce, cs, co = nonzero(lower <= distance[..., None] + _F(1e-3))
        if cb.size:
            d = _pair_distance(outlines, radii, box_of(cb, ce, cs), box_of(cb, co, cs))
            np.minimum.at(distance, (cb, ce, cs), d.astype(_F))
    # A box with a NaN, an infinity or a huge value has no usable bound, and its distances may be NaN,
    # which the official all-pairs minimum passes on: its valid pairs are all evaluated exactly, the
    # self pair too (officially offset by 1e10, not left out: it counts for NaN, and for boxes over
    # 512 m wide, whose self distance + 1e10 rounds below 1e10).
    exhaustive = unbounded_boxes(x, y, length, width, cos_h, sin_h) | (np.minimum(length, width) > _F(256))
    if exhaustive.any():
        pair = (exhaustive[:, :e, None] | exhaustive[:, None]) & valid[:, :e, None] & valid[:, None]
        ub, ue, uo, us = nonzero(pair)
        d = _pair_distance(outlines, radii, box_of(ub, ue, us), box_of(ub, uo, us)).astype(_F)
        d = np.where(ue == uo, d + EXTREMELY_LARGE_DISTANCE, d)
        np.minimum.at(distance, (ub, ue, us), d)
    return distance.reshape(*lead, e, num_steps)


# Beyond this magnitude (metres) the float32 margins of the distance bounds no longer hold.
BOUNDED_MAGNITUDE = _F(1e6)


def unbounded_boxes(*values):
    """Boxes with a value that is NaN, infinite or beyond `BOUNDED_MAGNITUDE`: bool, the values' shape `(...)`.

    The pruned searches skip pairs by bounds that only hold for finite,
    moderate values; these boxes are searched exhaustively instead.
    """
    out = np.zeros(np.shape(values[0]), dtype=bool)
    for value in values:
        with np.errstate(invalid="ignore"):
            out |= ~(np.abs(value) <= BOUNDED_MAGNITUDE)
    return out


def ego_frame_offsets(x, y, length, width, heading, ego_cos, ego_sin, num_evaluated: int):
    """Where every object lies in each evaluated object's frame.

    Args:
      x, y, length, width, heading: float32 `(..., num_objects)`.
      ego_cos, ego_sin: float32 `(..., num_evaluated, 1)`, cos and sin of minus
        the evaluated objects' headings.
    Returns:
      (ahead_of_front, beside_path, yaw_diff), float32 `(..., num_evaluated, num_objects)`:
      the other centre's distance ahead of the front, its lateral distance
      outside the path, and the absolute heading difference.
    """
    xp = array_namespace(x, ego_cos)
    e = slice(0, num_evaluated)
    dx = x[..., None, :] - x[..., e, None]
    dy = y[..., None, :] - y[..., e, None]
    if is_numpy(xp):
        # rel_x = cos dx - sin dy, rel_y = sin dx + cos dy, in place (the same float32 operations).
        rel_x = ego_cos * dx
        rel_y = np.multiply(ego_sin, dx, out=dx)
        rel_x -= np.multiply(ego_sin, dy)
        rel_y += np.multiply(ego_cos, dy, out=dy)
        ahead_of_front = rel_x
        ahead_of_front -= length[..., e, None] / _F(2)
        beside_path = np.abs(rel_y, out=rel_y)
        beside_path -= width[..., e, None] / _F(2)
        yaw_diff = heading[..., None, :] - heading[..., e, None]
        np.abs(yaw_diff, out=yaw_diff)
        return ahead_of_front, beside_path, yaw_diff
    rel_x = ego_cos * dx - ego_sin * dy
    rel_y = ego_sin * dx + ego_cos * dy
    ahead_of_front = rel_x - length[..., e, None] / _F(2)
    beside_path = xp.abs(rel_y) - width[..., e, None] / _F(2)
    yaw_diff = xp.abs(heading[..., None, :] - heading[..., e, None])
    return ahead_of_front, beside_path, yaw_diff


def following_gap(ahead_of_front, beside_path, yaw_diff, yaw_cos, yaw_sin, other_length, other_width):
    """Longitudinal gap to the other box and whether it is being followed.

    Args: float32 arrays `(...)` per (evaluated, other) pair; `yaw_cos`,
      `yaw_sin` of `yaw_diff`. Pairs must already be known aligned within 75
      degrees and the other object valid.
    Returns:
      (long_distance float32, following bool), `(...)`.
    """
    xp = array_namespace(ahead_of_front, yaw_cos)
    half_l = other_length / _F(2)
    half_w = other_width / _F(2)
    long_distance = ahead_of_front - (half_l * xp.abs(yaw_cos) + half_w * xp.abs(yaw_sin))
    lat_overlap = beside_path - (half_l * xp.abs(yaw_sin) + half_w * xp.abs(yaw_cos))
    following = ((long_distance > 0) & (lat_overlap < 0)
                 & ((lat_overlap < -SMALL_OVERLAP_THRESHOLD) | (yaw_diff <= MAX_HEADING_DIFF_FOR_SMALL_OVERLAP)))
    return long_distance, following


def capped_time_to_collision(gap, closing):
    """gap / closing speed, capped at 5 s; 5 s when not closing in. float32 `(...)`."""
    xp = array_namespace(gap, closing)
    with errstate(xp, divide="ignore", invalid="ignore", over="ignore"):
        return xp.where(closing > 0, xp.minimum(divide(gap, closing), MAXIMUM_TIME_TO_COLLISION),
                        MAXIMUM_TIME_TO_COLLISION)


def time_to_collision(x, y, length, width, heading, valid, num_evaluated: int, seconds_per_step: float,
                      steps: slice = slice(None), *, speed=None, ego_tail=None, pair_tail=None):
    """Seconds until each evaluated object hits the object it follows, at constant speeds.

    The followed object is the nearest valid one ahead, roughly aligned
    (heading difference up to 75 degrees, up to 10 when the lateral overlap is
    under 0.5 m) and overlapping the object's straight path. The result is
    capped at 5 s, which is also returned when nothing is followed.

    Args:
      x, y, length, width, heading: float32 `(..., num_objects, num_steps)`,
        the whole trajectories (speeds need neighbouring steps).
      valid: bool `(..., num_objects, num_steps)`.
      steps: the steps to evaluate.
      speed: float32 `(..., num_objects, num_steps)`, the planar speed, if
        already computed.
      ego_tail, pair_tail: the official ops' trailing packets, bool
        `(len(steps), num_evaluated, 1)` and `(len(steps), num_evaluated,
        num_objects)`; computed from the shapes when not given (they are given
        for padded arrays).
    Returns:
      float32 `(..., num_evaluated, len(steps))`.
    """
    num_objects, num_steps = x.shape[-2:]
    if speed is None:
        speed = linear_speed(x, y, np.zeros_like(x), seconds_per_step)
    if ego_tail is None:
        ego_tail = packet_tail((num_steps, num_evaluated, 1))[steps]
    if pair_tail is None:
        pair_tail = packet_tail((num_steps, num_evaluated, num_objects))[steps]
    return _by_samples(_time_to_collision_chunk, (x, y, length, width, heading, speed, valid), num_evaluated,
                       steps=steps, ego_tail=ego_tail, pair_tail=pair_tail)


def _time_to_collision_chunk(x, y, length, width, heading, speed, valid, num_evaluated: int, steps: slice,
                             ego_tail: np.ndarray, pair_tail: np.ndarray):
    lead, num_objects = x.shape[:-2], x.shape[-2]
    # Work step-major like the official code: (batch, steps, objects).
    t = lambda a: np.ascontiguousarray(np.swapaxes(a[..., steps], -1, -2)).reshape(
        (-1,) + a[..., steps].shape[-1:] + (num_objects,))
    x, y, length, width, heading, speed, valid = map(t, (x, y, length, width, heading, speed, valid))
    e = slice(0, num_evaluated)
    # Ego frame for every pair: (batch, steps, num_evaluated, num_objects).
    minus_yaw = -heading[..., e, None]
    ego_sin, ego_cos = sincos32(minus_yaw, ego_tail)
    ahead_of_front, beside_path, yaw_diff = ego_frame_offsets(x, y, length, width, heading,
                                                              ego_cos, ego_sin, num_evaluated)
    # Only pairs that can be "following" need the other box's extents: its
    # offsets are non-negative and at most its half-diagonal, so a pair must be
    # ahead of the front (the float32 sign of a difference is exact), beside
    # the path within that half-diagonal, and aligned within 75 degrees.
    reach = _F(0.5) * np.hypot(length, width) * _F(1 + 1e-5) + _F(1e-6)
    maybe = ahead_of_front > 0
    maybe &= beside_path < reach[..., None, :]
    maybe &= yaw_diff <= MAX_HEADING_DIFF
    maybe &= valid[..., None, :]
    b, st, ev, ob = nonzero(maybe)
    pair_tail = np.broadcast_to(pair_tail, maybe.shape)
    yd = yaw_diff[b, st, ev, ob]
    yaw_sin, yaw_cos = sincos32(yd, pair_tail[b, st, ev, ob])
    long_distance, following = following_gap(ahead_of_front[b, st, ev, ob], beside_path[b, st, ev, ob], yd,
                                             yaw_cos, yaw_sin, length[b, st, ob], width[b, st, ob])
    ttc = np.full(maybe.shape[:-1], MAXIMUM_TIME_TO_COLLISION, dtype=_F)
    if following.any():
        b, st, ev, ob, long_distance = (a[following] for a in (b, st, ev, ob, long_distance))
        group = (b * maybe.shape[1] + st) * num_evaluated + ev
        # The nearest followed object, ties to the lowest object index.
        _, best = first_minimum(group, long_distance, ob)
        b, st, ev, ob, gap = b[best], st[best], ev[best], ob[best], long_distance[best]
        ttc[b, st, ev] = capped_time_to_collision(gap, speed[b, st, ev] - speed[b, st, ob])
    # Nothing followed: the official code divides a gap of about 1e10 by the
    # closing speed and caps it, which is always the cap.
    # Steps where a box is NaN, infinite or huge (valid or not) or a speed is not finite: the official
    # all-objects search, whose gaps of -inf and NaN the pruning above would skip.
    irregular = unbounded_boxes(x, y, heading, length, width).any(axis=-1) | ~np.isfinite(speed).all(axis=-1)
    rb, rst = np.nonzero(irregular)
    if rb.size:
        ttc[rb, rst] = all_objects_time_to_collision(
            ahead_of_front[rb, rst], beside_path[rb, rst], yaw_diff[rb, rst], pair_tail[rb, rst],
            length[rb, rst, None], width[rb, rst, None], valid[rb, rst, None], speed[rb, rst], num_evaluated)
    return np.swapaxes(ttc, -1, -2).reshape(*lead, num_evaluated, -1)


def all_objects_time_to_collision(ahead_of_front, beside_path, yaw_diff, pair_tail, length, width, valid, speed,
                                  num_evaluated: int):
    """The official computation over every object (numpy or JAX): the JAX kernel, and numpy's
    steps with non-finite or huge values, where the pruned search would skip -inf and NaN gaps.

    Args:
      ahead_of_front, beside_path, yaw_diff: float32 `(..., num_evaluated, num_objects)` (`ego_frame_offsets`).
      pair_tail: bool `(..., num_evaluated, num_objects)`, the official ops' trailing packets.
      length, width: float32 `(..., 1, num_objects)`; valid: bool `(..., 1, num_objects)`.
      speed: float32 `(..., num_objects)`.
    Returns:
      float32 `(..., num_evaluated)`.
    """
    xp = array_namespace(ahead_of_front, speed)
    with errstate(xp, invalid="ignore", over="ignore"):
        yaw_sin, yaw_cos = sincos32(yaw_diff, pair_tail)
        long_distance, following = following_gap(ahead_of_front, beside_path, yaw_diff, yaw_cos, yaw_sin,
                                                  length, width)
        # Pairs not followed are pushed 1e10 away, not removed: -inf and NaN gaps stay what they are,
        # and the nearest is the first strict minimum (ties to the lowest object index, NaN never).
        followed = valid & following & (yaw_diff <= MAX_HEADING_DIFF)
        masked = long_distance + xp.where(followed, _F(0), EXTREMELY_LARGE_DISTANCE)
        ahead = strict_argmin(masked)
        gap = xp.take_along_axis(masked, ahead[..., None], axis=-1)[..., 0]
        closing = speed[..., :num_evaluated] - xp.take_along_axis(speed, ahead, axis=-1)
    return capped_time_to_collision(gap, closing)
