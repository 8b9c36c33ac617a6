"""Time to collision: how long until an evaluated object reaches the object it follows.

Per evaluated object and step, the nearest object ahead of its front within its path (heading within
75 degrees, lateral overlap), the gap to it divided by the closing speed, capped at 5 s (5 s when
nothing is followed or the gap opens). Objects are laid out as in `interaction`: the evaluated objects
first (`num_evaluated` of them), then every other sim agent.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import numba
import numpy as np

from wosac_eval.features import ops
from wosac_eval.features.compiled import cached_loop, compiled
from wosac_eval.features.float32_math import HUGE_COS, HUGE_SIN, packet_sincos, packet_tail, sincos32
from wosac_eval.features.interaction import EXTREMELY_LARGE_DISTANCE, unbounded_boxes
from wosac_eval.features.kinematics import linear_speed
from wosac_eval.features.search_strategy import TimeToCollisionInputs
from wosac_eval.features.spatial import strict_argmin
from wosac_eval.features.xp import array_namespace, errstate

_F = np.float32
MAX_HEADING_DIFF = _F(math.radians(75.0))
MAX_HEADING_DIFF_FOR_SMALL_OVERLAP = _F(math.radians(10.0))
SMALL_OVERLAP_THRESHOLD = _F(0.5)
MAXIMUM_TIME_TO_COLLISION = _F(5.0)


def frame_offsets(
    x: Any,
    y: Any,
    x_ego: Any,
    y_ego: Any,
    ego_cos: Any,
    ego_sin: Any,
    ego_length: Any,
    ego_width: Any,
    heading: Any,
    heading_ego: Any,
) -> Any:
    """Where an object lies in an evaluated object's frame (an `ops` kernel, per pair).

    Args: float32 `(...)`; `ego_cos`, `ego_sin` of minus the evaluated object's heading.
    Returns:
      (ahead_of_front, beside_path, yaw_diff), float32 `(...)`: the other centre's distance ahead
      of the front, its lateral distance outside the path, and the absolute heading difference.
    """
    dx, dy = x - x_ego, y - y_ego
    rel_x = ego_cos * dx - ego_sin * dy
    rel_y = ego_sin * dx + ego_cos * dy
    return (rel_x - ego_length / _F(2), ops.absolute(rel_y) - ego_width / _F(2), ops.absolute(heading - heading_ego))


def ego_frame_offsets(
    x: Any, y: Any, length: Any, width: Any, heading: Any, ego_cos: Any, ego_sin: Any, num_evaluated: int
) -> Any:
    """`frame_offsets` of every object in each evaluated object's frame.

    Args:
      x, y, length, width, heading: float32 `(..., num_objects)`.
      ego_cos, ego_sin: float32 `(..., num_evaluated, 1)`, cos and sin of minus
        the evaluated objects' headings.
    Returns:
      (ahead_of_front, beside_path, yaw_diff), float32 `(..., num_evaluated, num_objects)`.
    """
    e = slice(0, num_evaluated)
    return frame_offsets(
        x[..., None, :],
        y[..., None, :],
        x[..., e, None],
        y[..., e, None],
        ego_cos,
        ego_sin,
        length[..., e, None],
        width[..., e, None],
        heading[..., None, :],
        heading[..., e, None],
    )


def following_gap(
    ahead_of_front: Any,
    beside_path: Any,
    yaw_diff: Any,
    yaw_cos: Any,
    yaw_sin: Any,
    other_length: Any,
    other_width: Any,
) -> Any:
    """Longitudinal gap to the other box and whether it is being followed (an `ops` kernel).

    Args: float32 `(...)` per (evaluated, other) pair; `yaw_cos`, `yaw_sin` of
      `yaw_diff`. Pairs must already be known aligned within 75 degrees and the
      other object valid.
    Returns:
      (long_distance float32, following bool), `(...)`.
    """
    half_l = other_length / _F(2)
    half_w = other_width / _F(2)
    long_distance = ahead_of_front - (half_l * ops.absolute(yaw_cos) + half_w * ops.absolute(yaw_sin))
    lat_overlap = beside_path - (half_l * ops.absolute(yaw_sin) + half_w * ops.absolute(yaw_cos))
    following = (
        (long_distance > _F(0))
        & (lat_overlap < _F(0))
        & ((lat_overlap < -SMALL_OVERLAP_THRESHOLD) | (yaw_diff <= MAX_HEADING_DIFF_FOR_SMALL_OVERLAP))
    )
    return long_distance, following


def capped_time_to_collision(gap: Any, closing: Any) -> Any:
    """gap / closing speed, capped at 5 s; 5 s when not closing in (an `ops` kernel). float32 `(...)`."""
    return ops.where(
        closing > _F(0), ops.minimum(ops.divide(gap, closing), MAXIMUM_TIME_TO_COLLISION), MAXIMUM_TIME_TO_COLLISION
    )


def time_to_collision(inputs: TimeToCollisionInputs) -> np.ndarray:
    """Seconds until each evaluated object hits the object it follows, at constant speeds.

    The followed object is the nearest valid one ahead, roughly aligned
    (heading difference up to 75 degrees, up to 10 when the lateral overlap is
    under 0.5 m) and overlapping the object's straight path. The result is
    capped at 5 s, which is also returned when nothing is followed.

    Args:
      inputs: the whole trajectories `(..., num_objects, num_steps)` (speeds need neighbouring steps),
        the evaluated objects (the first of the object axis) and the steps to evaluate; the speeds
        and the official ops' trailing packets are computed where not given (they are given for
        padded arrays).
    Returns:
      float32 `(..., num_evaluated, len(steps))`.
    """
    i = _completed(inputs)
    lead, num_evaluated = inputs.x.shape[:-2], i.num_evaluated
    with np.errstate(invalid="ignore", over="ignore"):
        # Only pairs that can be "following" need the other box's extents: its offsets are
        # non-negative and at most its half-diagonal, so a pair must be ahead of the front (the
        # float32 sign of a difference is exact), beside the path within that half-diagonal, and
        # aligned within 75 degrees.
        reach = _F(0.5) * np.hypot(i.length, i.width) * _F(1 + 1e-5) + _F(1e-6)
        ttc = _followed_search(
            i.x,
            i.y,
            i.length,
            i.width,
            i.heading,
            i.speed,
            i.valid,
            reach,
            i.ego_tail,
            i.pair_tail,
            i.steps.start,
            len(range(i.steps.start, i.steps.stop)),
            num_evaluated,
        )
        _search_irregular_steps(i, ttc)
    return ttc.reshape(*lead, num_evaluated, -1)


def _completed(inputs: TimeToCollisionInputs) -> TimeToCollisionInputs:
    """`inputs` with the speeds and the tails computed where not given, the arrays contiguous
    `(batch, num_objects, num_steps)` (any leading axes flattened), the tails `(num_steps, num_evaluated)`
    and `(num_steps, num_evaluated, num_objects)`, and the steps a range of step indices."""
    i = inputs
    num_objects, num_steps = i.x.shape[-2:]
    speed = i.speed
    if speed is None:
        if i.seconds_per_step is None:
            raise ValueError("time_to_collision needs the speeds or the seconds per step")
        with np.errstate(invalid="ignore", over="ignore"):
            speed = linear_speed(i.x, i.y, np.zeros_like(i.x), i.seconds_per_step)
    reported = range(num_steps)[i.steps]
    if reported.step != 1:
        raise ValueError(f"time_to_collision takes a contiguous range of steps, not {i.steps}")
    ego_tail = packet_tail((num_steps, i.num_evaluated, 1))[i.steps] if i.ego_tail is None else i.ego_tail
    pair_tail = packet_tail((num_steps, i.num_evaluated, num_objects))[i.steps] if i.pair_tail is None else i.pair_tail
    flat = lambda a: np.ascontiguousarray(np.reshape(a, (-1, num_objects, num_steps)))  # noqa: E731
    return dataclasses.replace(
        i,
        x=flat(i.x),
        y=flat(i.y),
        length=flat(i.length),
        width=flat(i.width),
        heading=flat(i.heading),
        valid=flat(i.valid),
        speed=flat(speed),
        steps=slice(reported.start, reported.stop),
        ego_tail=np.ascontiguousarray(np.broadcast_to(ego_tail, (len(reported), i.num_evaluated, 1))[..., 0]),
        pair_tail=np.ascontiguousarray(np.broadcast_to(pair_tail, (len(reported), i.num_evaluated, num_objects))),
    )


def _search_irregular_steps(i: TimeToCollisionInputs, ttc: np.ndarray) -> None:
    """The steps where a box is NaN, infinite or huge (valid or not) or a speed is infinite, searched
    over all objects as officially, into `ttc` `(batch, num_evaluated, num_steps)`: the pruned search
    would skip their gaps of -inf and NaN, and a closing speed of +inf gives 0 s even where nothing is
    followed. A NaN speed needs no such step (the first and last steps of every track have one): any
    closing speed with it is NaN, hence the cap, in both searches alike. `i`: `_completed` inputs."""
    at = lambda a: a[..., i.steps]  # noqa: E731
    irregular = unbounded_boxes(*map(at, (i.x, i.y, i.heading, i.length, i.width))).any(axis=1)
    rb, rst = np.nonzero(irregular | np.isinf(at(i.speed)).any(axis=1))
    if not rb.size:
        return
    pick = lambda a: np.swapaxes(at(a), 1, 2)[rb, rst]  # noqa: E731  (pairs, objects)
    n = i.num_evaluated
    # The ego frames, as the official op computes them (shape: steps, evaluated, 1).
    ego_sin, ego_cos = sincos32(-pick(i.heading)[:, :n, None], i.ego_tail[rst][..., None])
    length, width = pick(i.length), pick(i.width)
    ahead, beside, yaw_diff = ego_frame_offsets(
        pick(i.x), pick(i.y), length, width, pick(i.heading), ego_cos, ego_sin, n
    )
    ttc[rb, :, rst] = all_objects_time_to_collision(
        FollowedPairs(
            ahead, beside, yaw_diff, i.pair_tail[rst], length[:, None], width[:, None], pick(i.valid)[:, None]
        ),
        pick(i.speed),
        n,
    )


_frame_offsets = compiled(frame_offsets)
_following_gap = compiled(following_gap)
_capped_time_to_collision = compiled(capped_time_to_collision)
_packet_sincos = compiled(packet_sincos)


@numba.njit
def _sincos32(x: Any, libm: Any) -> Any:
    """`float32_math.sincos32` of one value; `libm`: it is in the official op's trailing packet."""
    sin, cos = _packet_sincos(x)
    huge_finite = math.isfinite(x) and abs(x) >= HUGE_COS
    if libm or (huge_finite and abs(x) >= HUGE_SIN):
        sin = np.float32(math.sin(np.float64(x)))
    if libm or huge_finite:
        cos = np.float32(math.cos(np.float64(x)))
    return sin, cos


@cached_loop
def _followed_search(
    x: Any,
    y: Any,
    length: Any,
    width: Any,
    heading: Any,
    speed: Any,
    valid: Any,
    reach: Any,
    ego_tail: Any,
    pair_tail: Any,
    first: Any,
    num_reported: Any,
    num_evaluated: Any,
) -> Any:
    """Time to collision with the nearest followed object, at `num_reported` steps from `first` (compiled).

    Args:
      x, y, length, width, heading, speed, reach: float32 `(batch, num_objects, num_steps)`;
        valid bool, the same.
      ego_tail: bool `(num_steps, num_evaluated)`, pair_tail bool `(num_steps, num_evaluated, num_objects)`:
        the official ops' trailing packets.
    Returns:
      float32 `(batch, num_evaluated, num_steps)`.
    """
    batch, num_objects, num_steps = x.shape
    out = np.full((batch, num_evaluated, num_reported), MAXIMUM_TIME_TO_COLLISION, np.float32)
    # One step's objects, contiguous, and every object's offsets in one evaluated object's frame.
    step = np.empty((5, num_objects), np.float32)  # x, y, length, width, heading
    step_reach = np.empty(num_objects, np.float32)  # -inf for an invalid object: never beside the path
    ahead = np.empty(num_objects, np.float32)
    beside = np.empty(num_objects, np.float32)
    yaw_diff = np.empty(num_objects, np.float32)
    maybe = np.empty(num_objects, np.bool_)
    for b in range(batch):
        for st in range(num_reported):
            t = first + st
            for o in range(num_objects):
                step[0, o], step[1, o], step[2, o] = x[b, o, t], y[b, o, t], length[b, o, t]
                step[3, o], step[4, o] = width[b, o, t], heading[b, o, t]
                step_reach[o] = reach[b, o, t] if valid[b, o, t] else -np.inf
            for e in range(num_evaluated):
                # The ego frame, as the official op computes it (of minus the heading).
                ego_sin, ego_cos = _sincos32(-step[4, e], ego_tail[st, e])
                for o in range(num_objects):  # branch-free: the compiler vectorises it
                    ahead[o], beside[o], yaw_diff[o] = _frame_offsets(
                        step[0, o],
                        step[1, o],
                        step[0, e],
                        step[1, e],
                        ego_cos,
                        ego_sin,
                        step[2, e],
                        step[3, e],
                        step[4, o],
                        step[4, e],
                    )
                    maybe[o] = (ahead[o] > 0) & (beside[o] < step_reach[o]) & (yaw_diff[o] <= MAX_HEADING_DIFF)
                best, best_o = np.float32(np.inf), -1
                for o in range(num_objects):
                    if not maybe[o]:  # most objects: a branch the processor predicts
                        continue
                    yaw_sin, yaw_cos = _sincos32(yaw_diff[o], pair_tail[st, e, o])
                    gap, following = _following_gap(
                        ahead[o], beside[o], yaw_diff[o], yaw_cos, yaw_sin, step[2, o], step[3, o]
                    )
                    if following and gap < best:  # the nearest, ties to the lowest object index
                        best, best_o = gap, o
                if best_o >= 0:
                    # Nothing followed: the official code divides a gap of about 1e10 by the closing
                    # speed and caps it, which is always the cap.
                    out[b, e, st] = _capped_time_to_collision(best, speed[b, e, t] - speed[b, best_o, t])
    return out


class FollowedPairs(NamedTuple):
    """Each (evaluated object, other object) pair as the followed-object test reads it (numpy or JAX).

    Attributes:
      ahead_of_front, beside_path, yaw_diff: float32 `(..., num_evaluated, num_objects)` (`ego_frame_offsets`).
      pair_tail: bool `(..., num_evaluated, num_objects)`, the official ops' trailing packets.
      length, width: float32 `(..., 1, num_objects)`, the other object's box; valid: bool `(..., 1, num_objects)`.
    (Any layout of the pairs, each array broadcast to one shape.)
    """

    ahead_of_front: Any
    beside_path: Any
    yaw_diff: Any
    pair_tail: Any
    length: Any
    width: Any
    valid: Any


def followed_gaps(pairs: FollowedPairs) -> Any:
    """The gap to each other object, 1e10 more where it is not followed: float32, the pairs' shape `(...)`.

    Elementwise (numpy or JAX, pairs in any layout). Pairs not followed are pushed 1e10 away, not
    removed: -inf and NaN gaps stay what they are.
    """
    p = pairs
    xp = array_namespace(p.ahead_of_front, p.yaw_diff)
    with errstate(xp, invalid="ignore", over="ignore"):
        yaw_sin, yaw_cos = sincos32(p.yaw_diff, p.pair_tail)
        long_distance, following = following_gap(
            p.ahead_of_front, p.beside_path, p.yaw_diff, yaw_cos, yaw_sin, p.length, p.width
        )
        followed = p.valid & following & (p.yaw_diff <= MAX_HEADING_DIFF)
        return long_distance + xp.where(followed, _F(0), EXTREMELY_LARGE_DISTANCE)


def all_objects_time_to_collision(pairs: FollowedPairs, speed: Any, num_evaluated: int) -> Any:
    """The official computation over every object (numpy or JAX): the JAX kernel, and numpy's
    steps with non-finite or huge values, where the pruned search would skip -inf and NaN gaps.

    Args:
      pairs: `(..., num_evaluated, num_objects)` (see `FollowedPairs`).
      speed: float32 `(..., num_objects)`.
    Returns:
      float32 `(..., num_evaluated)`.
    """
    xp = array_namespace(pairs.ahead_of_front, speed)
    masked = followed_gaps(pairs)
    with errstate(xp, invalid="ignore", over="ignore"):
        # The nearest is the first strict minimum (ties to the lowest object index, NaN never).
        ahead = strict_argmin(masked)
        gap = xp.take_along_axis(masked, ahead[..., None], axis=-1)[..., 0]
        closing = speed[..., :num_evaluated] - xp.take_along_axis(speed, ahead, axis=-1)
    return capped_time_to_collision(gap, closing)
