"""Property test: the vectorised rollout rules agree with a plain reference on random ScenarioRollouts.

Random scenes mix every fault (wrong joint-scene counts, missing / extra /
duplicated / unset object ids, short and long fields, NaN and infinities), so
both the stacked fast path and the per-field fallback are exercised.
"""

from __future__ import annotations

import math
import os

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.validate import rules

N_STEPS = 80
N_ROLLOUTS = 3
AGENTS = [3, 7, 300, 70000]  # 70000 needs a 3-byte varint
POOL = AGENTS + [5, -2]

values = st.one_of(
    st.floats(width=32, allow_nan=False, allow_infinity=False),
    st.sampled_from([math.nan, math.inf, -math.inf]),
)
lengths = st.sampled_from([N_STEPS, N_STEPS, N_STEPS, 0, N_STEPS - 1, N_STEPS + 1])


@st.composite
def trajectory(draw):
    t = sim_agents_submission_pb2.SimulatedTrajectory()
    object_id = draw(st.one_of(st.none(), st.sampled_from(POOL)))
    if object_id is not None:
        t.object_id = object_id
    for name in rules.TRAJECTORY_FIELDS:
        n = draw(lengths)
        base = draw(st.floats(-1e4, 1e4, width=32))
        field = getattr(t, name)
        field.extend([base] * n)
        for _ in range(draw(st.integers(0, 2))):
            if n:
                field[draw(st.integers(0, n - 1))] = draw(values)
    if draw(st.booleans()):  # optional fields must not disturb the checks
        t.width.extend([1.0] * draw(st.integers(0, 3)))
        t.object_type = 1
    return t


@st.composite
def scenario_rollouts(draw):
    r = sim_agents_submission_pb2.ScenarioRollouts(scenario_id="s")
    for _ in range(draw(st.integers(0, N_ROLLOUTS + 1))):
        scene = r.joint_scenes.add()
        if draw(st.booleans()):  # mostly right: exactly the agents
            for oid in draw(st.permutations(AGENTS)):
                t = draw(trajectory())
                t.object_id = oid
                scene.simulated_trajectories.add().CopyFrom(t)
        else:
            for t in draw(st.lists(trajectory(), max_size=6)):
                scene.simulated_trajectories.add().CopyFrom(t)
    return r


def reference(r, agents) -> set[tuple]:
    """The findings as (code, rollout, object_id, field, detail number), computed the obvious way."""
    out = set()
    if len(r.joint_scenes) != N_ROLLOUTS:
        out.add(("rollouts.wrong_count", None, None, None, len(r.joint_scenes)))
    for i, scene in enumerate(r.joint_scenes):
        ids = []
        for k, t in enumerate(scene.simulated_trajectories):
            oid = t.object_id if t.HasField("object_id") else None
            if oid is None:
                out.add(("rollouts.missing_object_id", i, None, None, k))
            else:
                ids.append(oid)
            for name in rules.TRAJECTORY_FIELDS:
                vals = list(getattr(t, name))
                if len(vals) != N_STEPS:
                    out.add(("rollouts.wrong_length", i, oid, name, len(vals)))
                bad = [j for j, v in enumerate(vals) if not math.isfinite(v)]
                if bad:
                    out.add(("rollouts.non_finite", i, oid, name, bad[0]))
        if len(set(ids)) != len(ids):
            out.add(("rollouts.duplicate_objects", i, None, None, len(ids) - len(set(ids))))
        if agents is not None:
            if set(agents) - set(ids):
                out.add(("rollouts.missing_sim_agents", i, None, None, len(set(agents) - set(ids))))
            if set(ids) - set(agents):
                out.add(("rollouts.extra_objects", i, None, None, len(set(ids) - set(agents))))
    return out


def observed(findings) -> set[tuple]:
    out = set()
    for f in findings:
        detail = f.message.rsplit(": ", 1)[-1]
        if f.code == "rollouts.wrong_count":
            number = int(detail.split()[1])
        elif f.code == "rollouts.missing_object_id":
            number = int(detail.split("[")[1].split("]")[0])
        elif f.code == "rollouts.wrong_length":
            number = int(detail.split(" has ")[1].split()[0])
        elif f.code == "rollouts.non_finite":
            number = int(detail.split("[")[1].split("]")[0])
        elif f.code == "rollouts.duplicate_objects":
            number = sum(int(part.split("(")[1].split()[0]) - 1 for part in detail.split(", "))
        else:  # missing / extra: count the listed ids
            number = len(detail.split("[")[1].split("]")[0].split(", "))
        out.add((f.code, f.rollout, f.object_id, f.field, number))
    return out


@settings(max_examples=int(os.environ.get("WOSAC_FUZZ_EXAMPLES", "150")), deadline=None)
@given(r=scenario_rollouts(), known=st.booleans())
def test_vectorised_rules_match_reference(r, known):
    agents = np.array(AGENTS) if known else None
    findings = rules.check_scenario_rollouts(r, agents, shard="x", n_rollouts=N_ROLLOUTS)
    assert observed(findings) == reference(r, agents)
    # a round trip through bytes (as read from a file) gives the same findings
    again = sim_agents_submission_pb2.ScenarioRollouts.FromString(r.SerializeToString())
    assert [f.message for f in rules.check_scenario_rollouts(again, agents, shard="x", n_rollouts=N_ROLLOUTS)] == [
        f.message for f in findings
    ]
