"""`criticality_features.pairwise_interaction` (a compiled loop over pairs and steps) gives, bit for bit, what
the plain array definition gives: on demo and real scenes, crowded lattices, standing and touching boxes,
non-finite and tied values."""

from __future__ import annotations

import numpy as np
import pytest

from support.paths import require_shared
from wosac_eval.analysis.criticality_features import (
    MIN_CLOSING,
    NEAR_MISS_GAP,
    NEAR_MISS_SPEED,
    PAIR_RANGE,
    TTC_HORIZON,
    disc_gap,
    disc_pairs,
    interacting_pairs,
    kinematic_volatility,
    pairwise_interaction,
)
from wosac_eval.arrays.object_types import TYPE_CYCLIST, TYPE_PEDESTRIAN, TYPE_VEHICLE
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.arrays.trajectories import ObjectTrajectories
from wosac_eval.parse.scenarios import read_scenarios
from wosac_eval.sim import scenes


def plain_definition(log, velocity, pedestrian):
    """The pairs that can interact (`interacting_pairs`, which both share) at every step where both are valid
    and one moves, by array operations over the entries: the disc pairs' gap, the first touch at constant
    velocities and the near miss."""
    vx, vy, v_valid = velocity
    x, y, heading = (np.asarray(a, dtype=np.float64) for a in (log.x, log.y, log.heading))
    length, width = np.asarray(log.length, np.float64), np.asarray(log.width, np.float64)
    n, steps = x.shape
    ttc, closing, near = np.full(steps, np.inf), np.zeros(steps), np.zeros(steps)
    if n < 2:
        return ttc, closing, near
    i, j = interacting_pairs(x, y, v_valid, pedestrian)  # the same pairs: what is compared is the entries
    moving = v_valid & (np.hypot(vx, vy) >= MIN_CLOSING / 2)
    pair, t = np.nonzero(v_valid[i] & v_valid[j] & (moving[i] | moving[j]))
    a, b = i[pair], j[pair]
    dxc, dyc = x[b, t] - x[a, t], y[b, t] - y[a, t]
    ux, uy = vx[b, t] - vx[a, t], vy[b, t] - vy[a, t]
    relative_speed = np.hypot(ux, uy)
    centre_distance = np.hypot(dxc, dyc)
    reach = (centre_distance - (length[a, t] + length[b, t]) / 2 < np.maximum(3.0, TTC_HORIZON * relative_speed)) & (
        centre_distance < PAIR_RANGE
    )
    a, b, t = a[reach], b[reach], t[reach]
    dxc, dyc, ux, uy, relative_speed = dxc[reach], dyc[reach], ux[reach], uy[reach], relative_speed[reach]
    if t.size == 0:
        return ttc, closing, near
    dx, dy, radius = disc_pairs(
        dxc, dyc, heading[a, t], length[a, t], width[a, t], heading[b, t], length[b, t], width[b, t]
    )
    distance2 = dx * dx + dy * dy
    gap = disc_gap(dx, dy, radius)
    speed2 = (relative_speed**2)[:, None, None]
    approach = dx * ux[:, None, None] + dy * uy[:, None, None]
    c = distance2 - radius**2
    disc = approach**2 - speed2 * c
    with np.errstate(invalid="ignore", divide="ignore"):
        t_hit = (-approach - np.sqrt(np.maximum(disc, 0.0))) / speed2
    course = (c > 0) & (approach < 0) & (disc >= 0) & (t_hit <= TTC_HORIZON) & (speed2 >= MIN_CLOSING**2)
    entry_ttc = np.where(course, t_hit, np.inf).min(axis=(1, 2))
    np.minimum.at(ttc, t, entry_ttc)
    np.maximum.at(closing, t, np.where(np.isfinite(entry_ttc), relative_speed, 0.0))
    np.maximum.at(near, t, np.exp(-gap / NEAR_MISS_GAP) * relative_speed / (relative_speed + NEAR_MISS_SPEED))
    return ttc, closing, near


def _inputs(log: ObjectTrajectories):
    types = np.asarray(log.object_type)
    velocity = kinematic_volatility(log, np.isin(types, (TYPE_VEHICLE, TYPE_CYCLIST)))[4]
    return log, velocity, types == TYPE_PEDESTRIAN


def _assert_same(log: ObjectTrajectories) -> None:
    with np.errstate(invalid="ignore", over="ignore"):
        got = pairwise_interaction(*_inputs(log))
        want = plain_definition(*_inputs(log))
    for name, g, w in zip(("time_to_collision", "closing_speed", "near_miss"), got, want):
        np.testing.assert_array_equal(g, w, err_msg=name, strict=True)


def _log(x, y, heading, length, width, valid, types) -> ObjectTrajectories:
    f = np.float32
    n, steps = x.shape
    return ObjectTrajectories(
        x=x.astype(f),
        y=y.astype(f),
        z=np.zeros((n, steps), f),
        heading=heading.astype(f),
        length=length.astype(f),
        width=width.astype(f),
        height=np.full((n, steps), 1.5, f),
        valid=valid,
        object_id=np.arange(n, dtype=np.int64),
        object_type=np.asarray(types, np.int64),
    )


@pytest.mark.parametrize("seed", range(6))
def test_demo_scenes(seed):
    for scenario in scenes.generate_scenes(4, seed=seed):
        arrays = scenario_arrays(scenario)
        _assert_same(arrays.log.take_ids(arrays.sim_agent_ids))


def test_real_scenes():
    for scenario in read_scenarios(require_shared("womd") / "womd"):
        arrays = scenario_arrays(scenario)
        _assert_same(arrays.log.take_ids(arrays.sim_agent_ids))


@pytest.mark.parametrize("seed", range(8))
def test_crowded_moving_lattice(seed):
    """Boxes on a 2-3 m lattice at right-angle headings, driving at random speeds (many ties, touching boxes,
    collision courses from every side), some pedestrians and invalid steps."""
    rng = np.random.default_rng(seed)
    n, steps = 24, 91
    grid = np.stack(np.meshgrid(np.arange(6), np.arange(4)), axis=-1).reshape(-1, 2)[:n] * rng.choice([2.0, 2.5, 3.0])
    speed = rng.choice([0.0, 0.3, 1.0, 5.0, 12.0], size=(n, 1)) * rng.choice([-1, 1], size=(n, 2))
    t = np.arange(steps) * 0.1
    x = grid[:, :1] + speed[:, :1] * t
    y = grid[:, 1:] + speed[:, 1:] * t
    heading = np.broadcast_to(rng.choice([0.0, np.pi / 2, np.pi, -np.pi / 2], size=(n, 1)), (n, steps))
    length = np.broadcast_to(rng.choice([0.5, 2.0, 4.5, 12.0], size=(n, 1)), (n, steps))
    width = np.broadcast_to(rng.choice([0.5, 2.0, 2.5], size=(n, 1)), (n, steps))
    valid = rng.random((n, steps)) > 0.05
    types = rng.choice([TYPE_VEHICLE, TYPE_PEDESTRIAN, TYPE_CYCLIST], size=n)
    _assert_same(_log(x, y, heading, length, width, valid, types))


def test_non_finite_and_degenerate_values():
    """NaN and infinite positions, headings and sizes at valid steps, boxes wider than long, zero sizes,
    objects that stand still at one point, and a scene of one object and of none."""
    rng = np.random.default_rng(7)
    n, steps = 12, 91
    x = rng.normal(0, 4, (n, 1)) + rng.normal(0, 3, (n, 1)) * np.arange(steps) * 0.1
    y = rng.normal(0, 4, (n, 1)) + rng.normal(0, 3, (n, 1)) * np.arange(steps) * 0.1
    heading = rng.uniform(-np.pi, np.pi, (n, steps))
    length, width = rng.uniform(0, 6, (n, steps)), rng.uniform(0, 3, (n, steps))
    x[0, 40:50], y[1, 30] = np.nan, np.inf
    heading[2, 20:60], length[3, 10:20], width[4, 50] = np.nan, np.nan, np.inf
    x[5], y[5] = x[6], y[6]  # standing still on one another
    x[5, :], y[5, :] = 1.0, 1.0
    x[6, :], y[6, :] = 1.0, 1.0
    valid = np.ones((n, steps), bool)
    types = np.full(n, TYPE_VEHICLE)
    _assert_same(_log(x, y, heading, length, width, valid, types))
    _assert_same(_log(x[:1], y[:1], heading[:1], length[:1], width[:1], valid[:1], types[:1]))
    _assert_same(_log(x[:0], y[:0], heading[:0], length[:0], width[:0], valid[:0], types[:0]))
