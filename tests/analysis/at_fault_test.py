"""`driving_scores.at_fault`: measuring only the objects that can be the SDC's nearest gives every answer that
measuring all of them does, on crowded, tied and non-finite scenes."""

from __future__ import annotations

import numpy as np
import pytest

from wosac_eval.analysis.criticality_features import disc_gap, disc_pairs
from wosac_eval.analysis.driving_scores import at_fault, rollouts_at_fault
from wosac_eval.arrays.rollouts import RolloutArrays


def every_object(rollouts: RolloutArrays, sizes, rollout, step, sdc) -> np.ndarray:
    """The plain definition: the disc gap to every other object, the nearest (lowest row among ties) the partner."""
    pick = lambda a: np.asarray(np.broadcast_to(a, rollouts.x.shape)[rollout, :, step], np.float64)  # noqa: E731
    x, y, heading, length, width = map(pick, (rollouts.x, rollouts.y, rollouts.heading, *sizes))
    entries = np.arange(rollout.size)
    gap = np.empty(x.shape)
    for j in range(x.shape[1]):
        dx, dy, radius = disc_pairs(
            x[:, j] - x[entries, sdc],
            y[:, j] - y[entries, sdc],
            heading[entries, sdc],
            length[entries, sdc],
            width[entries, sdc],
            heading[:, j],
            length[:, j],
            width[:, j],
        )
        with np.errstate(invalid="ignore"):
            gap[:, j] = disc_gap(dx, dy, radius)
    gap[entries, sdc] = np.inf
    partner = np.argmin(gap, axis=1)
    along = (x[entries, partner] - x[entries, sdc]) * np.cos(heading[entries, sdc]) + (
        y[entries, partner] - y[entries, sdc]
    ) * np.sin(heading[entries, sdc])
    return along > -length[entries, sdc] / 2


def scene(seed: int, objects: int, spread: float, grid: bool) -> tuple[RolloutArrays, tuple]:
    """Random rollouts (4 x objects x 6 steps) and box sizes; `grid`: positions on a 2 m lattice with
    headings of 0 or 90 degrees and two box sizes, where many objects tie for the nearest."""
    rng = np.random.default_rng(seed)
    shape = (4, objects, 6)
    if grid:
        x = rng.integers(-3, 4, shape).astype(np.float32) * 2
        y = rng.integers(-3, 4, shape).astype(np.float32) * 2
        heading = rng.integers(0, 2, shape).astype(np.float32) * np.float32(np.pi / 2)
        length = rng.choice(np.float32([4.0, 2.0]), (1, objects, 1)) * np.ones(shape, np.float32)
        width = np.full(shape, 2.0, np.float32)
    else:
        x, y = (rng.normal(0, spread, shape).astype(np.float32) for _ in range(2))
        heading = rng.uniform(-np.pi, np.pi, shape).astype(np.float32)
        length = rng.uniform(0.5, 12, shape).astype(np.float32)
        width = rng.uniform(0.5, 3, shape).astype(np.float32)
    ids = np.tile(np.arange(objects), (4, 1))
    return RolloutArrays("s", ids, x, y, np.zeros(shape, np.float32), heading), (length, width)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("objects, spread, grid", [(2, 3.0, False), (30, 4.0, False), (30, 60.0, False), (25, 0, True)])
def test_the_nearest_partner_is_every_objects(seed, objects, spread, grid):
    rollouts, sizes = scene(seed, objects, spread, grid)
    rng = np.random.default_rng(seed + 100)
    rollout, step, sdc = rng.integers(0, 4, 200), rng.integers(0, 6, 200), rng.integers(0, objects, 200)
    np.testing.assert_array_equal(
        at_fault(rollouts, sizes, rollout, step, sdc), every_object(rollouts, sizes, rollout, step, sdc)
    )


def test_a_non_finite_position_is_answered_as_by_every_object():
    rollouts, sizes = scene(0, 12, 5.0, False)
    rollouts.x[1, 3, 2] = np.nan
    rollouts.y[2, 5, :] = np.inf
    rollout, step, sdc = np.repeat(np.arange(4), 12), np.tile(np.arange(6), 8), np.tile(np.arange(12), 4)
    with np.errstate(invalid="ignore"):
        np.testing.assert_array_equal(
            at_fault(rollouts, sizes, rollout, step, sdc), every_object(rollouts, sizes, rollout, step, sdc)
        )


@pytest.mark.parametrize("seed", range(4))
def test_rollouts_at_fault_is_any_entry_at_fault(seed):
    """Tested in rounds, stopping at a rollout's first entry at fault: per rollout, the OR of every entry's
    answer, on rollouts with no collision entry, a few and one at every step, their partners ahead of and
    behind the SDC."""
    rng = np.random.default_rng(seed)
    num_rollouts, objects, steps = 12, 10, 80
    shape = (num_rollouts, objects, steps)
    x, y = (rng.normal(0, 4.0, shape).astype(np.float32) for _ in range(2))
    heading = rng.uniform(-np.pi, np.pi, shape).astype(np.float32)
    rollouts = RolloutArrays(
        "s", np.tile(np.arange(objects), (num_rollouts, 1)), x, y, np.zeros(shape, np.float32), heading
    )
    sizes = (rng.uniform(0.5, 12, shape).astype(np.float32), rng.uniform(0.5, 3, shape).astype(np.float32))
    sdc_rows = rng.integers(0, objects, num_rollouts)
    share = rng.choice([0.0, 0.03, 0.5, 1.0], size=(num_rollouts, 1))
    rollout, step = np.nonzero(rng.random((num_rollouts, steps)) < share)
    answers = at_fault(rollouts, sizes, rollout, step, sdc_rows[rollout])
    every = np.zeros(num_rollouts, dtype=bool)
    np.logical_or.at(every, rollout, answers)
    np.testing.assert_array_equal(rollouts_at_fault(rollouts, sizes, rollout, step, sdc_rows), every)
    assert answers.any() and not answers.all()  # entries of both answers, so skipping some could matter


def test_a_rollout_at_fault_only_late_in_its_collisions():
    """The SDC rear-ended at every step (not at fault), but in rollout k its partner is ahead of it from step
    10 k on: found in the rounds after the first few, whatever the round the step falls in."""
    num_rollouts, steps = 8, 80
    shape = (num_rollouts, 2, steps)
    x = np.zeros(shape, np.float32)
    x[:, 1] = -4.0  # the partner's centre behind the SDC's rear bumper (SDC length 4.5)
    for k in range(1, num_rollouts):
        x[k, 1, 10 * k :] = 4.0
    rollouts = RolloutArrays(
        "s",
        np.tile(np.arange(2), (num_rollouts, 1)),
        x,
        np.zeros(shape, np.float32),
        np.zeros(shape, np.float32),
        np.zeros(shape, np.float32),
    )
    sizes = (np.full(shape, 4.5, np.float32), np.full(shape, 2.0, np.float32))
    rollout, step = np.nonzero(np.ones((num_rollouts, steps), bool))
    got = rollouts_at_fault(rollouts, sizes, rollout, step, np.zeros(num_rollouts, np.int64))
    np.testing.assert_array_equal(got, np.arange(num_rollouts) > 0)
    none = np.zeros(0, np.int64)
    np.testing.assert_array_equal(
        rollouts_at_fault(rollouts, sizes, none, none, np.zeros(num_rollouts, np.int64)), np.zeros(num_rollouts, bool)
    )
