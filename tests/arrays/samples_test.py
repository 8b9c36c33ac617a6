"""Rollouts may list their agents in different orders: each is laid out by its own order."""

from __future__ import annotations

import dataclasses
import gzip
from pathlib import Path

import numpy as np

from support.paths import TEST_DATA
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.arrays.samples import rollout_samples
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import sim_agents_submission_pb2

DATA = TEST_DATA / "oracle"


def _case():
    case = sorted(DATA.glob("*.binproto.gz"))[0]
    raw = gzip.decompress(case.read_bytes())
    rollouts = rollout_arrays(
        sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw).scenario_rollouts[0]
    )
    scenario = next(s for s, _ in iter_scenarios(DATA / "scenes") if s.scenario_id == rollouts.scenario_id)
    return scenario_arrays(scenario), rollouts


def simulated_trajectories(scenario, rollouts):
    return rollout_samples(scenario, rollouts)[0]


def _take(rollouts, rows, order=None):
    def pick(a):
        if a is None or order is None:
            return a if a is None else a[rows]
        return np.take_along_axis(a[rows], order.reshape(order.shape + (1,) * (a.ndim - 2)), axis=1)

    fields = ("object_id", "x", "y", "z", "heading", "length", "width", "height", "object_type")
    return dataclasses.replace(rollouts, **{f: pick(getattr(rollouts, f)) for f in fields})


def test_each_rollout_is_laid_out_by_its_own_agent_order():
    scenario, rollouts = _case()
    rng = np.random.default_rng(5)
    rows = np.arange(rollouts.num_rollouts)
    order = np.stack([rng.permutation(rollouts.object_id.shape[1]) for _ in rows])
    shuffled = _take(rollouts, rows, order)
    assert not (shuffled.object_id == shuffled.object_id[0]).all()
    together = simulated_trajectories(scenario, shuffled)
    for r in rows:
        alone = simulated_trajectories(scenario, _take(shuffled, rows[r : r + 1]))
        for field in dataclasses.fields(alone):
            np.testing.assert_array_equal(
                getattr(together, field.name)[r], getattr(alone, field.name)[0], err_msg=f"rollout {r}, {field.name}"
            )
    # Same order everywhere (the common case) gives the same layout as the general path.
    same = _take(rollouts, rows, np.broadcast_to(order[0], order.shape))
    uniform = simulated_trajectories(scenario, same)
    np.testing.assert_array_equal(uniform.object_id, np.broadcast_to(together.object_id[0], uniform.object_id.shape))
