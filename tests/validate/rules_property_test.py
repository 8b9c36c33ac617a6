"""Property test: the vectorised rollout rules agree with a plain reference on random ScenarioRollouts.

Random scenes mix every fault (wrong joint-scene counts, missing / extra /
duplicated / unset object ids, short and long fields, NaN and infinities; for
scenario gen also box sizes that are missing, short, non-finite or not
positive, and missing object types), so both the stacked fast path and the
per-field fallback are exercised, for both challenges.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wosac_eval.parse.wire import varint
from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.validate import rules

N_ROLLOUTS = 3
STEPS = {"sim_agents": 80, "scenario_gen": 91}
AGENTS = [3, 7, 300, 70000]  # 70000 needs a 3-byte varint
POOL = AGENTS + [5, -2]

values = st.one_of(
    st.floats(width=32, allow_nan=False, allow_infinity=False),
    st.sampled_from([math.nan, math.inf, -math.inf]),
)


@st.composite
def trajectory(draw, challenge="sim_agents"):
    n_steps = STEPS[challenge]
    lengths = st.sampled_from([n_steps, n_steps, n_steps, 0, n_steps - 1, n_steps + 1])
    t = sim_agents_submission_pb2.SimulatedTrajectory()
    object_id = draw(st.one_of(st.none(), st.sampled_from(POOL)))
    if object_id is not None:
        t.object_id = object_id
    box_fields = rules.BOX_FIELDS if challenge == "scenario_gen" else ()
    for name in rules.TRAJECTORY_FIELDS + box_fields:
        n = draw(lengths)
        base = draw(st.floats(0.5, 20, width=32) if name in box_fields else st.floats(-1e4, 1e4, width=32))
        field = getattr(t, name)
        field.extend([base] * n)
        for _ in range(draw(st.integers(0, 2))):
            if n:
                field[draw(st.integers(0, n - 1))] = draw(
                    st.one_of(values, st.sampled_from([0.0, -1.0])) if name in box_fields else values
                )
    if challenge == "scenario_gen":
        object_type = draw(st.sampled_from([None, 0, 1, 2, 3]))
        if object_type is not None:
            t.object_type = object_type
        if draw(st.booleans()):
            t.valid.extend(draw(st.lists(st.booleans(), max_size=3)))
    elif draw(st.booleans()):  # fields the challenge ignores must not disturb the checks, and are reported
        for name in draw(st.sets(st.sampled_from(rules.BOX_FIELDS))):
            getattr(t, name).extend([1.0] * draw(st.integers(0, 3)))
        t.valid.extend(draw(st.lists(st.booleans(), max_size=2)))
        if draw(st.booleans()):
            t.object_type = draw(st.sampled_from([0, 1]))  # set, even to TYPE_UNSET
    return t


@st.composite
def scenario_rollouts(draw, challenge="sim_agents"):
    r = sim_agents_submission_pb2.ScenarioRollouts(scenario_id="s")
    for _ in range(draw(st.integers(0, N_ROLLOUTS + 1))):
        scene = r.joint_scenes.add()
        if draw(st.booleans()):  # mostly right: exactly the agents
            for oid in draw(st.permutations(AGENTS)):
                t = draw(trajectory(challenge))
                t.object_id = oid
                scene.simulated_trajectories.add().CopyFrom(t)
        else:
            for t in draw(st.lists(trajectory(challenge), max_size=6)):
                scene.simulated_trajectories.add().CopyFrom(t)
    return r


def reference(r, agents, challenge="sim_agents") -> set[tuple]:
    """The findings as (code, rollout, object_id, field, detail number), computed the obvious way."""
    n_steps = STEPS[challenge]
    boxes = challenge == "scenario_gen"
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
            for name in rules.TRAJECTORY_FIELDS + (rules.BOX_FIELDS if boxes else ()):
                vals = list(getattr(t, name))
                if len(vals) != n_steps:
                    out.add(("rollouts.wrong_length", i, oid, name, len(vals)))
                bad = [j for j, v in enumerate(vals) if not math.isfinite(v)]
                if bad:
                    out.add(("rollouts.non_finite", i, oid, name, bad[0]))
                if name in rules.BOX_FIELDS:
                    small = [j for j, v in enumerate(vals) if math.isfinite(v) and v <= 0]
                    if small:
                        out.add(("rollouts.non_positive_size", i, oid, name, small[0]))
            if boxes and not (t.HasField("object_type") and t.object_type != 0):
                out.add(("rollouts.missing_object_type", i, oid, "object_type", 0))
        if len(set(ids)) != len(ids):
            out.add(("rollouts.duplicate_objects", i, None, None, len(ids) - len(set(ids))))
        if agents is not None:
            if set(agents) - set(ids):
                out.add(("rollouts.missing_sim_agents", i, None, None, len(set(agents) - set(ids))))
            if set(ids) - set(agents):
                out.add(("rollouts.extra_objects", i, None, None, len(set(ids) - set(agents))))
    trajectories = [t for scene in r.joint_scenes for t in scene.simulated_trajectories]
    if boxes:
        ignored = ["valid"] if any(not all(t.valid) for t in trajectories if len(t.valid)) else []
    else:
        ignored = [n for n in ("length", "width", "height", "valid") if any(len(getattr(t, n)) for t in trajectories)]
        ignored += ["object_type"] if any(t.HasField("object_type") for t in trajectories) else []
    if ignored:
        out.add(("rollouts.ignored_field", None, None, ignored[0], len(ignored)))
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
        elif f.code in ("rollouts.non_finite", "rollouts.non_positive_size"):
            number = int(detail.split("[")[1].split("]")[0])
        elif f.code == "rollouts.missing_object_type":
            number = 0
        elif f.code == "rollouts.ignored_field":
            detail = f.message.split("fields ", 1)[1].split(" are set")[0]
            number = len(detail.split(", "))
        elif f.code == "rollouts.duplicate_objects":
            number = sum(int(part.split("(")[1].split()[0]) - 1 for part in detail.split(", "))
        else:  # missing / extra: count the listed ids
            number = len(detail.split("[")[1].split("]")[0].split(", "))
        out.add((f.code, f.rollout, f.object_id, f.field, number))
    return out


def unpacked_valid(r) -> bytes:
    """`r` serialized with every trajectory's `valid` unpacked (a varint field per value), as a writer
    other than protobuf's own may send it and every parser must read it."""

    def field(number: int, payload: bytes) -> bytes:
        return varint(number << 3 | 2) + varint(len(payload)) + payload

    head = sim_agents_submission_pb2.ScenarioRollouts()
    head.CopyFrom(r)
    head.ClearField("joint_scenes")
    out = head.SerializeToString()
    for scene in r.joint_scenes:
        body = b""
        for t in scene.simulated_trajectories:
            rest = sim_agents_submission_pb2.SimulatedTrajectory()
            rest.CopyFrom(t)
            rest.ClearField("valid")
            body += field(1, rest.SerializeToString() + b"".join(varint(11 << 3) + varint(int(v)) for v in t.valid))
        out += field(2, body)
    return out


def _check(r, known, challenge):
    agents = np.array(AGENTS) if known else None
    findings = rules.check_scenario_rollouts(r, agents, shard="x", n_rollouts=N_ROLLOUTS, challenge=challenge)
    assert observed(findings) == reference(r, agents, challenge)
    # a round trip through bytes (as read from a file) gives the same findings
    again = sim_agents_submission_pb2.ScenarioRollouts.FromString(r.SerializeToString())
    assert [
        f.message
        for f in rules.check_scenario_rollouts(again, agents, shard="x", n_rollouts=N_ROLLOUTS, challenge=challenge)
    ] == [f.message for f in findings]
    # read from the bytes it was parsed from (as validation reads a shard), whatever their encoding
    for data in (r.SerializeToString(), unpacked_valid(r)):
        parsed = sim_agents_submission_pb2.ScenarioRollouts.FromString(data)
        assert parsed == r
        assert [
            f.message
            for f in rules.check_scenario_rollouts(
                parsed, agents, shard="x", n_rollouts=N_ROLLOUTS, challenge=challenge, wire_bytes=memoryview(data)
            )
        ] == [f.message for f in findings]


@settings(max_examples=int(os.environ.get("WOSAC_FUZZ_EXAMPLES", "150")), deadline=None)
@given(r=scenario_rollouts(), known=st.booleans())
@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_vectorised_rules_match_reference(r, known):
    _check(r, known, "sim_agents")


@settings(max_examples=int(os.environ.get("WOSAC_FUZZ_EXAMPLES", "150")), deadline=None)
@given(r=scenario_rollouts("scenario_gen"), known=st.booleans())
@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_vectorised_scenario_gen_rules_match_reference(r, known):
    _check(r, known, "scenario_gen")
