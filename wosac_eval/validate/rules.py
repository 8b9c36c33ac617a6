"""The validation rules, as pure functions from parsed messages to findings.

Three families:
- metadata rules on one `SimAgentsChallengeSubmission` shard (and consistency
  of the metadata between shards): `validate.metadata_rules`;
- coverage rules: the submitted scenario ids against the scenario set:
  `validate.coverage_rules`;
- rollout rules on one `ScenarioRollouts` (this module, `validate.rules`): 32 joint scenes, each with exactly
  the sim agents (objects valid at the current step, index 10), each simulated
  trajectory with 80 (sim agents) or 91 (scenario gen) finite values in
  center_x, center_y, center_z, heading; for scenario gen also in length,
  width and height, and (warnings: the official scores them) positive sizes
  and an object_type. Fields the challenge's evaluator ignores are reported as
  warnings.

The per-value checks are vectorised over a whole scenario: its trajectories
are flattened to shape `(num_trajectories,)` (32 joint scenes x num_objects), the
fields of every trajectory are read from the scenario's serialized bytes at once
(`parse.wire_walks`: value counts, non-finite and non-positive values, object ids
and types), and lengths, finiteness and object ids are
checked with numpy on whole arrays, not with Python loops over values. Only faulty trajectories and scenes are looked
at one by one, to name the fault precisely.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.object_types import PROTO_NAMES, TYPE_UNSET
from wosac_eval.arrays.rollouts import trajectory_headers, trajectory_spans
from wosac_eval.challenges import CURRENT_TIME_INDEX
from wosac_eval.parse import wire_walks
from wosac_eval.parse.wire import BOX_FIELDS, TRAJECTORY_FIELD_NUMBERS, VALID_FIELD_NUMBER
from wosac_eval.validate.findings import WARNING, Finding, Location, format_ids, make_finding

if TYPE_CHECKING:  # the messages checked; the checks read their fields and need no import of the classes
    from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2

N_ROLLOUTS = challenges.NUM_ROLLOUTS  # joint scenes required per scenario
N_SIMULATION_STEPS = challenges.spec("sim_agents").num_simulation_steps  # 8 s at 10 Hz after the current step
TRAJECTORY_FIELDS = ("center_x", "center_y", "center_z", "heading")


def sim_agent_ids(scenario: scenario_pb2.Scenario) -> np.ndarray:
    """Sorted unique ids of the scenario's objects valid at the current step, shape `(num_objects,)`.

    A track too short to have a current step has no valid state there.
    """
    return np.unique(challenges.sim_agent_ids(scenario))


@dataclasses.dataclass(frozen=True)
class _FieldChecks:
    """What the wire says of each trajectory of a scenario, in joint-scene order.

    counts, non_finite, non_positive: per trajectory and field, its number of values and whether one is
      not finite, or (box sizes only) finite and <= 0, each shape `(num_trajectories, num_fields)`.
    ids, has_id, has_type: the object id, whether it is set, and whether an object_type is set (not
      TYPE_UNSET), each shape `(num_trajectories,)`.
    ignored: the fields set that the challenge's evaluator does not read (`_ignored_fields`).
    """

    counts: np.ndarray
    non_finite: np.ndarray
    non_positive: np.ndarray
    ids: np.ndarray
    has_id: np.ndarray
    has_type: np.ndarray
    ignored: list[str]


def _field_checks(
    rollouts: Any, fields: Sequence[str], n_trajectories: int, spec: challenges.ChallengeSpec
) -> _FieldChecks:
    """The checks of every trajectory of `rollouts` (`_FieldChecks`), read from the scenario's serialized
    bytes at once (`parse.wire_walks`)."""

    data = wire_walks.message_bytes(rollouts)
    start, end, _, _ = trajectory_spans(data)
    if len(start) != n_trajectories:
        raise AssertionError("the wire and the parsed message disagree on the number of trajectories")
    # The box sizes are walked for either challenge: for sim agents only to say whether they are set.
    walked = tuple(fields) + tuple(f for f in BOX_FIELDS if f not in fields)
    numbers = np.array([TRAJECTORY_FIELD_NUMBERS[f] for f in walked], np.int64)
    _, counts, non_finite, non_positive = wire_walks.float_fields(data, start, end, numbers, 0)
    ids, has_id, object_type, type_set = trajectory_headers(data, start, end)
    valid_count, valid_false = wire_walks.bool_fields(data, start, end, VALID_FIELD_NUMBER)
    set_in_some = np.asarray(counts.any(axis=0))  # `(num_fields,)` (numpy's stubs allow a scalar: asarray)
    ignored = _ignored_fields(spec, dict(zip(walked, set_in_some)), valid_count, valid_false, type_set)
    k = len(fields)
    non_positive = non_positive[:, :k] & np.isin(fields, BOX_FIELDS)
    return _FieldChecks(counts[:, :k], non_finite[:, :k], non_positive, ids, has_id, object_type != TYPE_UNSET, ignored)


def _ignored_fields(
    spec: challenges.ChallengeSpec,
    set_in_some: dict[str, bool],
    valid_count: np.ndarray,
    valid_false: np.ndarray,
    type_set: np.ndarray,
) -> list[str]:
    """Fields set in some trajectory that the challenge's evaluator does not read.

    set_in_some: float field -> whether some trajectory holds a value of it; valid_count, valid_false,
    type_set: per trajectory, its `valid` values, whether one is false, whether object_type is set.
    """
    if spec.submits_boxes:
        # Scenario gen: validity is the log's at the current step, whatever is submitted.
        return ["valid"] if valid_false.any() else []
    names = [name for name in BOX_FIELDS if set_in_some[name]]
    if valid_count.any():
        names.append("valid")
    if type_set.any():
        names.append("object_type")
    return names


_IGNORED_WHY = {
    True: "the scenario gen evaluator takes every sim agent as valid at every step (the log's validity "
    "at step 10), whatever the submitted valid says",
    False: "the sim agents evaluator takes box sizes and object types from the log (sizes at step 10) and "
    "every simulated step as valid; these fields count for --challenge scenario_gen only",
}


def _length_detail(count: int, field_index: int, n_steps: int) -> str:
    """What a field of the wrong length is, and what the official evaluator does with it."""
    field = (TRAJECTORY_FIELDS + BOX_FIELDS)[field_index]
    detail = f"field {field} has {count} values, expected {n_steps}"
    if field_index < len(TRAJECTORY_FIELDS):
        return detail + "; the official validator refuses it"
    # Box sizes: the official validator does not look at them, but its scorer stacks them with the
    # positions per step and fails on the scenario when their length differs.
    return detail + "; the official validator accepts it but its scorer fails on the scenario"


def _length_hint(count: int, field_index: int, spec: challenges.ChallengeSpec) -> str | None:
    """The likely cause of a wrong length (printed once per cause, not on every finding): the other
    challenge's length, or missing box sizes."""
    other = next(s for s in challenges.SPECS.values() if s is not spec)
    if count == other.num_simulation_steps and field_index < len(TRAJECTORY_FIELDS):
        return (
            f"{count} values is a {other.challenge} submission: validate and score it with "
            f"--challenge {other.challenge}"
        )
    if field_index >= len(TRAJECTORY_FIELDS):
        return (
            f"the scenario gen challenge needs length, width and height with one value per step "
            f"({spec.num_simulation_steps}); with another count the official scorer cannot score the scenario"
        )
    return None


# The official validator does not look at values, and its scorer lets NaN and inf spread through the
# features to finite likelihoods (NaN or inf displacement errors); wosac-eval scores them the same way.
_NON_FINITE_OFFICIAL = (
    "; the official evaluator scores it as given, NaN spreading into its features (so does wosac-eval)"
)
_NON_FINITE_HINT = (
    "a NaN or inf position, heading or box size is almost always a simulator bug: the object's "
    "distances and speeds at those steps become NaN, and its displacement error NaN or inf"
)
_NON_POSITIVE_HINT = (
    "the official evaluator scores zero or negative sizes as given (so does wosac-eval); logged "
    "boxes are 0 on a track's invalid steps, so a log replay has them: check the sizes are meant"
)
_MISSING_TYPE_HINT = (
    "the official evaluator scores it as TYPE_UNSET (so does wosac-eval): the metrics take the "
    "types from the log, and the submitted type is only carried along"
)


def _non_finite_detail(field: str, values: Any) -> str:
    array = np.asarray(values, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(array))
    first = int(bad[0])
    kind = "NaN" if np.isnan(array[first]) else ("+inf" if array[first] > 0 else "-inf")
    detail = f"{field}[{first}] is {kind}"
    if len(bad) > 1:
        detail += f" ({len(bad)} non-finite values, at indices {format_ids(bad.tolist(), 10)})"
    return detail


def check_scene_object_ids(
    ids: np.ndarray,
    has_id: np.ndarray,
    sim_agent_ids: np.ndarray | None,
    *,
    shard: str | None,
    scenario_id: str | None,
    rollout: int,
) -> list[Finding]:
    """Object-id rules on one joint scene: no trajectory without an id, no duplicate, exactly the sim agents.

    ids, has_id: the scene's trajectories' object ids and whether each is set, shape `(num_trajectories,)`.
    sim_agent_ids: sorted unique int64 ids, shape `(num_objects,)`, or None when
    the scenario is unknown (then only missing ids and duplicates are checked).
    """
    out: list[Finding] = []
    loc = Location(shard, scenario_id, rollout)
    for k in np.flatnonzero(~has_id).tolist():
        out.append(make_finding("rollouts.missing_object_id", f"simulated_trajectories[{k}] has no object_id", loc))
    present, multiplicity = np.unique(ids[has_id], return_counts=True)
    repeated = multiplicity > 1
    if repeated.any():
        dup = ", ".join(f"{i} ({m} times)" for i, m in zip(present[repeated].tolist(), multiplicity[repeated].tolist()))
        out.append(
            make_finding(
                "rollouts.duplicate_objects",
                f"object ids simulated more than once: {dup}; the official "
                "validator accepts it but its scorer fails on the scenario (repeated ids)",
                loc,
            )
        )
    if sim_agent_ids is not None:
        missing = np.setdiff1d(sim_agent_ids, present, assume_unique=True)
        if missing.size:
            out.append(
                make_finding(
                    "rollouts.missing_sim_agents",
                    f"missing sim agents {format_ids(missing.tolist())} "
                    f"({missing.size} of {sim_agent_ids.size} objects valid at step {CURRENT_TIME_INDEX}); "
                    "the official validator refuses it",
                    loc,
                )
            )
        extra = np.setdiff1d(present, sim_agent_ids, assume_unique=True)
        if extra.size:
            out.append(
                make_finding(
                    "rollouts.extra_objects",
                    f"objects {format_ids(extra.tolist())} are not sim agents "
                    f"(not in the scenario, or not valid at step {CURRENT_TIME_INDEX}); the official validator "
                    "refuses it",
                    loc,
                )
            )
    return out


@dataclasses.dataclass(frozen=True)
class _Scenario:
    """One ScenarioRollouts being checked: its joint scenes, where each trajectory of the flat order is,
    and what the wire says of them.

    starts: the flat index of each scene's first trajectory, and the total, shape (num_scenes + 1,).
    rollout_of: each trajectory's joint scene, shape `(num_trajectories,)`.
    """

    location: Location  # its shard and scenario
    scenes: list
    starts: np.ndarray
    rollout_of: np.ndarray
    fields: tuple[str, ...]
    checks: _FieldChecks

    def at(self, k: int) -> Location:
        """Where the `k`th trajectory is: shard, scenario, its joint scene and its object (when set)."""
        checks = self.checks
        object_id = int(checks.ids[k]) if checks.has_id[k] else None
        return dataclasses.replace(self.location, rollout=int(self.rollout_of[k]), object_id=object_id)

    def values(self, k: int, field: str) -> np.ndarray:
        """The `k`th trajectory's values of a field (float64), read from its parsed message."""
        r = int(np.searchsorted(self.starts, k, side="right")) - 1
        trajectory = self.scenes[r].simulated_trajectories[k - int(self.starts[r])]
        return np.asarray(getattr(trajectory, field), dtype=np.float64)


def check_scenario_rollouts(
    rollouts: sim_agents_submission_pb2.ScenarioRollouts,
    sim_agent_ids: Sequence[int] | np.ndarray | None,
    *,
    shard: str | None = None,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    n_rollouts: int | None = None,
    n_steps: int | None = None,
    wire_bytes: bytes | memoryview | None = None,
) -> list[Finding]:
    """Rules on one ScenarioRollouts: n_rollouts joint scenes, each with exactly the sim agents, each
    trajectory with n_steps finite values in center_x, center_y, center_z and heading; for a challenge
    whose submissions carry boxes (scenario gen), also n_steps finite positive values in length, width
    and height and an object_type. Fields the challenge ignores are reported once, as a warning.

    sim_agent_ids: ids of the scenario's objects valid at step 10, shape
    `(num_objects,)`; None when the scenario is not in the scenario set.
    All joint scenes are checked together: the trajectories of the scenario
    are flattened to shape `(num_trajectories,)`, `rollout_of` maps each to its
    joint scene, and the checks run on whole arrays.
    wire_bytes: the serialized `rollouts` it was parsed from, when the caller has them (the checks read
    the wire; without them the message is serialized again).
    """
    spec = challenges.spec(challenge)
    n_rollouts = spec.num_rollouts if n_rollouts is None else n_rollouts
    n_steps = spec.num_simulation_steps if n_steps is None else n_steps
    location = Location(shard, rollouts.scenario_id or None)
    scenes = list(rollouts.joint_scenes)
    scene_sizes = np.fromiter(
        (len(scene.simulated_trajectories) for scene in scenes), dtype=np.int64, count=len(scenes)
    )
    starts = np.concatenate([[0], np.cumsum(scene_sizes)])
    fields = TRAJECTORY_FIELDS + (BOX_FIELDS if spec.submits_boxes else ())
    checks = _field_checks(rollouts if wire_bytes is None else wire_bytes, fields, int(scene_sizes.sum()), spec)
    scenario = _Scenario(location, scenes, starts, np.repeat(np.arange(len(scenes)), scene_sizes), fields, checks)
    expected = None if sim_agent_ids is None else np.unique(np.asarray(sim_agent_ids, dtype=np.int64))
    out: list[Finding] = []
    if len(scenes) != n_rollouts:
        out.append(
            make_finding(
                "rollouts.wrong_count",
                f"found {len(scenes)} joint scenes, expected {n_rollouts}; the official validator refuses it",
                location,
            )
        )
    out += _object_id_findings(scenario, scene_sizes, expected)
    out += _length_findings(scenario, n_steps, spec)
    out += _value_findings(scenario)
    if spec.submits_boxes:
        out += _missing_type_findings(scenario)
    if checks.ignored:
        out.append(
            make_finding(
                "rollouts.ignored_field",
                f"fields {', '.join(checks.ignored)} are set but ignored: {_IGNORED_WHY[spec.submits_boxes]}",
                location,
                field=checks.ignored[0],
                severity=WARNING,
            )
        )
    return out


def _object_id_findings(scenario: _Scenario, scene_sizes: np.ndarray, expected: np.ndarray | None) -> list[Finding]:
    """The object-id rules of every joint scene. The common case (every scene holds exactly the sim agents)
    is proven for all scenes at once; only the other scenes are looked at one by one."""
    ids, has_id, starts = scenario.checks.ids, scenario.checks.has_id, scenario.starts
    num_scenes = len(scenario.scenes)
    scene_ok = np.zeros(num_scenes, dtype=bool)
    if expected is not None and num_scenes and (scene_sizes == expected.size).all() and has_id.all():
        per_scene = np.sort(ids.reshape(num_scenes, expected.size), axis=1)
        scene_ok = (per_scene == expected).all(axis=1)
    out: list[Finding] = []
    location = scenario.location
    for r in np.flatnonzero(~scene_ok).tolist():
        span = slice(starts[r], starts[r + 1])
        out.extend(
            check_scene_object_ids(
                ids[span], has_id[span], expected, shard=location.shard, scenario_id=location.scenario_id, rollout=r
            )
        )
    return out


def _length_findings(scenario: _Scenario, n_steps: int, spec: challenges.ChallengeSpec) -> list[Finding]:
    """A finding per trajectory field whose number of values is not `n_steps`."""
    counts = scenario.checks.counts
    return [
        make_finding(
            "rollouts.wrong_length",
            _length_detail(int(counts[k, f]), f, n_steps),
            scenario.at(k),
            field=scenario.fields[f],
            hint=_length_hint(int(counts[k, f]), f, spec),
        )
        for k, f in np.argwhere(counts != n_steps).tolist()
    ]


def _value_findings(scenario: _Scenario) -> list[Finding]:
    """Warnings for non-finite values (any field), then for zero or negative box sizes."""
    out = []
    for k, f in np.argwhere(scenario.checks.non_finite).tolist():
        field = scenario.fields[f]
        detail = _non_finite_detail(field, scenario.values(k, field))
        out.append(
            make_finding(
                "rollouts.non_finite",
                detail + _NON_FINITE_OFFICIAL,
                scenario.at(k),
                field=field,
                severity=WARNING,
                hint=_NON_FINITE_HINT,
            )
        )
    for k, f in np.argwhere(scenario.checks.non_positive).tolist():
        field = scenario.fields[f]
        out.append(
            make_finding(
                "rollouts.non_positive_size",
                _non_positive_detail(field, scenario.values(k, field)),
                scenario.at(k),
                field=field,
                severity=WARNING,
                hint=_NON_POSITIVE_HINT,
            )
        )
    return out


def _non_positive_detail(field: str, values: np.ndarray) -> str:
    bad = np.flatnonzero(np.isfinite(values) & (values <= 0))
    detail = f"{field}[{bad[0]}] is {values[bad[0]]:g}"
    if len(bad) > 1:
        detail += f" ({len(bad)} such values, at indices {format_ids(bad.tolist(), 10)})"
    return detail + "; a box size is expected to be positive, the official evaluator scores it as given"


def _missing_type_findings(scenario: _Scenario) -> list[Finding]:
    """Warnings for trajectories without an object_type (the challenges whose submissions carry one)."""
    return [
        make_finding(
            "rollouts.missing_object_type",
            "object_type is not set (or TYPE_UNSET); expected the type of the object "
            f"({', '.join(PROTO_NAMES.values())}), the official evaluator scores it as "
            "TYPE_UNSET",
            scenario.at(k),
            field="object_type",
            severity=WARNING,
            hint=_MISSING_TYPE_HINT,
        )
        for k in np.flatnonzero(~scenario.checks.has_type).tolist()
    ]
