"""Dense JAX drivers of the feature kernels: fixed shapes, no candidate pruning.

The numpy path prunes candidate pairs with k-d trees and `np.nonzero`, whose
output sizes depend on the data. Under `jax.jit` shapes must be static, so
these drivers evaluate the SAME per-pair kernels (box_geometry, road_edge,
traffic_lights, interaction) over every pair of padded, masked arrays and
pick minima with `argmin`, which returns the first index among ties: the
lowest index wins, as in the numpy path. The pruned numpy search is proven
to return the all-pairs minimum, so both agree bit for bit.

Everything here expects float32 inputs that are already padded (invalid
padding masked by the `valid` arrays) and must be traced under
`jax.enable_x64(True)` (the float32 math rounds through float64).
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from wosac_eval.features import box_geometry, interaction, kinematics, road_edge, traffic_lights
from wosac_eval.features.float32_math import sincos32

_F = np.float32
# Pairs evaluated at once in the chunked searches (bounds the working memory).
PAIRS_PER_CHUNK = 1 << 22


def _chunked(fn, xs, chunk: int):
    """`fn` over the leading axis of the arrays `xs`, `chunk` rows at a time (via `lax.map`)."""
    n = jax.tree_util.tree_leaves(xs)[0].shape[0]
    if n <= chunk:
        return fn(xs)
    pad = (-n) % chunk
    padded = jax.tree_util.tree_map(
        lambda a: jnp.concatenate([a, jnp.zeros((pad,) + a.shape[1:], a.dtype)]) if pad else a, xs)
    grouped = jax.tree_util.tree_map(lambda a: a.reshape((-1, chunk) + a.shape[1:]), padded)
    out = lax.map(fn, grouped)
    return jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[2:])[:n], out)


def _columns(xyz):
    """x, y, z of float32 `(..., 3)`."""
    return xyz[..., 0], xyz[..., 1], xyz[..., 2]


def _rows_per_chunk(columns: int) -> int:
    return max(1, PAIRS_PER_CHUNK // max(1, columns))


def nearest_object_distance(x, y, length, width, cos_h, sin_h, valid, num_evaluated: int):
    """Dense `interaction.distance_to_nearest_object` for one sample.

    Args:
      x, y, length, width, cos_h, sin_h: float32 `(num_objects, num_steps)`.
      valid: bool `(num_objects, num_steps)`.
    Returns:
      float32 `(num_evaluated, num_steps)`; 1e10 where nothing valid is near.
    """
    num_objects = x.shape[0]
    radius = interaction.corner_radius(length, width)
    boxes = (x, y, length - _F(2) * radius, width - _F(2) * radius, cos_h, sin_h, radius)
    shape = (num_evaluated, num_objects) + x.shape[1:]
    a = tuple(jnp.broadcast_to(b[:num_evaluated, None], shape) for b in boxes)
    b = tuple(jnp.broadcast_to(b[None], shape) for b in boxes)
    d = interaction.rounded_box_distance(a, b)
    possible = valid[:num_evaluated, None] & valid[None]
    possible &= ~jnp.eye(num_evaluated, num_objects, dtype=bool)[..., None]
    d = jnp.where(possible, d, interaction.EXTREMELY_LARGE_DISTANCE)
    return jnp.minimum(d.min(axis=1), interaction.EXTREMELY_LARGE_DISTANCE)


def time_to_collision(x, y, length, width, heading, speed, valid, ego_tail, pair_tail, num_evaluated: int):
    """Dense `interaction.time_to_collision` for one sample, step-major.

    Args:
      x, y, length, width, heading, speed: float32 `(num_steps, num_objects)`.
      valid: bool `(num_steps, num_objects)`.
      ego_tail: bool `(num_steps, num_evaluated, 1)`, pair_tail: bool
        `(num_steps, num_evaluated, num_objects)`: the official ops' trailing
        packets, from the real (unpadded) shapes.
    Returns:
      float32 `(num_steps, num_evaluated)`.
    """
    e = slice(0, num_evaluated)
    minus_yaw = -heading[:, e, None]
    ego_sin, ego_cos = sincos32(minus_yaw, ego_tail)
    ahead, beside, yaw_diff = interaction.ego_frame_offsets(x, y, length, width, heading,
                                                            ego_cos, ego_sin, num_evaluated)
    yaw_sin, yaw_cos = sincos32(yaw_diff, pair_tail)
    gap, following = interaction.following_gap(ahead, beside, yaw_diff, yaw_cos, yaw_sin,
                                               length[:, None, :], width[:, None, :])
    following &= (ahead > 0) & (yaw_diff <= interaction.MAX_HEADING_DIFF) & valid[:, None, :]
    # The nearest followed object, ties to the lowest object index.
    best = jnp.argmin(jnp.where(following, gap, jnp.inf), axis=-1)
    best_gap = jnp.take_along_axis(gap, best[..., None], -1)[..., 0]
    closing = speed[:, e] - jnp.take_along_axis(speed, best, -1)
    ttc = interaction.capped_time_to_collision(best_gap, closing)
    return jnp.where(following.any(axis=-1), ttc, interaction.MAXIMUM_TIME_TO_COLLISION)


def signed_distance_to_road_edge(queries, segments):
    """Dense `road_edge.signed_distance_to_polylines`.

    Args:
      queries: float32 `(num_points, 3)`.
      segments: dict of the valid road-edge segments in official order, padded:
        start, delta, prior_start, prior_delta, next_start, next_delta float32
        `(num_segments, 3)`; valid, prior_valid, next_valid, convex_before,
        convex_after bool `(num_segments,)`.
    Returns:
      float32 `(num_points,)`, negative on the road side.
    """
    s = segments

    def nearest(q):
        d3 = road_edge.segment_distances(*_columns(q[:, None, :]), *_columns(s["start"][None]),
                                         *_columns(s["delta"][None]))[1]
        return jnp.argmin(jnp.where(s["valid"][None], d3, jnp.inf), axis=-1)

    best = _chunked(nearest, queries, _rows_per_chunk(s["start"].shape[0]))
    pick = {k: v[best] for k, v in s.items()}
    rel_t, _, d2 = road_edge.segment_distances(*_columns(queries), *_columns(pick["start"]),
                                               *_columns(pick["delta"]))
    xy = queries[:, :2]
    sign = road_edge.corner_sign(
        rel_t, road_edge.segment_side(xy, pick["start"], pick["delta"]),
        road_edge.segment_side(xy, pick["prior_start"], pick["prior_delta"]),
        road_edge.segment_side(xy, pick["next_start"], pick["next_delta"]),
        pick["convex_before"], pick["convex_after"], pick["prior_valid"], pick["next_valid"])
    return (sign * d2).astype(_F)


def nearest_lane_segment(xy, lane_start, lane_delta, lane_valid):
    """Dense `traffic_lights.nearest_lane_segment`: index into the given segments.

    Args:
      xy: float32 `(num_points, 2)`.
      lane_start, lane_delta: float32 `(num_segments, 2)`; lane_valid: bool `(num_segments,)`.
    Returns:
      int `(num_points,)`.
    """
    def nearest(q):
        d = traffic_lights.lane_measure(q[:, None, :], lane_start[None], lane_delta[None])
        return jnp.argmin(jnp.where(lane_valid[None], d, jnp.inf), axis=-1)

    return _chunked(nearest, xy, _rows_per_chunk(lane_start.shape[0]))


def sample_features(t, m, num_evaluated: int, seconds_per_step: float, future: slice, lights_from: int):
    """Per-step features of the evaluated objects for samples of one scenario.

    Args:
      t: dict of padded trajectories, float32 / bool `(num_samples, num_objects, num_steps)`:
        x, y, z, heading, length, width, height, valid; and the official
        trailing-packet masks heading_tail `(num_samples, num_objects, future steps)`,
        ego_tail `(num_samples, future steps, num_evaluated, 1)`,
        pair_tail `(num_samples, future steps, num_evaluated, num_objects)`.
      m: dict of padded map arrays: road-edge segments (see
        `signed_distance_to_road_edge`) and the red-light stop lines
        stop_start, stop_delta, stop_point float32 `(steps from lights_from, signals, 2)`,
        stopping bool `(steps from lights_from, signals)`.
    Returns:
      dict of `(num_samples, num_evaluated, future steps)` arrays, and
      red_light_suspect bool `(num_samples, num_evaluated, steps from lights_from, signals)`.
    """
    e = slice(0, num_evaluated)
    speed, accel, ang_speed, ang_accel = kinematics.kinematic_features(
        t["x"][:, e], t["y"][:, e], t["z"][:, e], t["heading"][:, e], seconds_per_step)
    f = lambda a: a[..., future]
    h = f(t["heading"])
    sin_h, cos_h = sincos32(h, t["heading_tail"])

    def per_sample(args):
        x, y, length, width, c, s, valid = args
        return nearest_object_distance(x, y, length, width, c, s, valid, num_evaluated)

    nearest = lax.map(per_sample, (f(t["x"]), f(t["y"]), f(t["length"]), f(t["width"]), cos_h, sin_h,
                                   f(t["valid"])))

    all_speed = kinematics.linear_speed(t["x"], t["y"], jnp.zeros_like(t["x"]), seconds_per_step)
    step_major = lambda a: jnp.swapaxes(f(a), -1, -2)
    ttc = jax.vmap(functools.partial(time_to_collision, num_evaluated=num_evaluated))(
        *map(step_major, (t["x"], t["y"], t["length"], t["width"], t["heading"], all_speed, t["valid"])),
        t["ego_tail"], t["pair_tail"])

    pick = lambda a: f(a[:, e])
    cx, cy = box_geometry.box_corners_xy(pick(t["x"]), pick(t["y"]), pick(t["length"]), pick(t["width"]),
                                         cos_h[:, e], sin_h[:, e])
    cz = jnp.broadcast_to((pick(t["z"]) + (-pick(t["height"]) * _F(0.5)))[..., None], cx.shape)
    corners = jnp.stack([cx, cy, cz], axis=-1)
    edge = signed_distance_to_road_edge(corners.reshape(-1, 3), m).reshape(cx.shape).max(axis=-1)
    edge = jnp.where(pick(t["valid"]), edge, -road_edge.EXTREMELY_LARGE_DISTANCE)

    lights = slice(lights_from, None)
    xy = jnp.stack([t["x"][:, e, lights], t["y"][:, e, lights]], axis=-1)
    suspect = traffic_lights.stop_line_crossings(xy, t["valid"][:, e, lights], m["stop_start"],
                                                 m["stop_delta"], m["stop_point"], m["stopping"])
    return {"linear_speed": f(speed), "linear_acceleration": f(accel), "angular_speed": f(ang_speed),
            "angular_acceleration": f(ang_accel), "distance_to_nearest_object": nearest,
            "time_to_collision": jnp.swapaxes(ttc, -1, -2), "distance_to_road_edge": edge,
            "red_light_suspect": suspect}
