"""The validation rules, as pure functions from parsed messages to findings.

Three families:
- metadata rules on one `SimAgentsChallengeSubmission` shard (and consistency
  of the metadata between shards);
- coverage rules: the submitted scenario ids against the scenario set;
- rollout rules on one `ScenarioRollouts`: 32 joint scenes, each with exactly
  the sim agents (objects valid at the current step, index 10), each simulated
  trajectory with 80 (sim agents) or 91 (scenario gen) finite values in
  center_x, center_y, center_z, heading; for scenario gen also in length,
  width and height, and (warnings: the official scores them) positive sizes
  and an object_type. Fields the challenge's evaluator ignores are reported as
  warnings.

The per-value checks are vectorised over a whole scenario: its trajectories
are flattened to shape (num_trajectories,) (32 joint scenes x num_objects), the
fields of every trajectory are read from the scenario's serialized bytes at once
(`parse.wire_walks`: value counts, non-finite and non-positive values, object ids
and types), and lengths, finiteness and object ids are
checked with numpy on whole arrays, not with Python loops over values. Only faulty trajectories and scenes are looked
at one by one, to name the fault precisely.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from typing import Any, TypedDict

import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.object_types import PROTO_NAMES, TYPE_UNSET
from wosac_eval.arrays.rollouts import trajectory_headers, trajectory_spans
from wosac_eval.challenges import CURRENT_TIME_INDEX
from wosac_eval.parse import wire_walks
from wosac_eval.parse.wire import BOX_FIELDS, TRAJECTORY_FIELD_NUMBERS, VALID_FIELD_NUMBER
from wosac_eval.validate.findings import WARNING, Finding, format_ids, make_finding

N_ROLLOUTS = challenges.NUM_ROLLOUTS  # joint scenes required per scenario
N_SIMULATION_STEPS = challenges.spec("sim_agents").num_simulation_steps  # 8 s at 10 Hz after the current step
TRAJECTORY_FIELDS = ("center_x", "center_y", "center_z", "heading")
SIM_AGENTS_SUBMISSION = 1  # SimAgentsChallengeSubmission.SubmissionType

# "200K", "1.5B", "7000000": a number, optionally with a multiplier suffix.
_PARAMETER_COUNT = re.compile(r"^\s*\d+(\.\d+)?\s*[KMBTkmbt]?\s*$")

_REQUIRED_TEXT = ("account_name", "unique_method_name", "affiliation", "description")
_REQUIRED_FLAGS = ("uses_lidar_data", "uses_camera_data", "uses_public_model_pretraining")
METADATA_FIELDS = (
    "submission_type",
    "account_name",
    "unique_method_name",
    "authors",
    "affiliation",
    "description",
    "method_link",
    "uses_lidar_data",
    "uses_camera_data",
    "uses_public_model_pretraining",
    "public_model_names",
    "num_model_parameters",
    "acknowledge_complies_with_closed_loop_requirement",
)


def sim_agent_ids(scenario: Any) -> np.ndarray:
    """Sorted unique ids of the scenario's objects valid at the current step, shape (num_sim_agents,).

    A track too short to have a current step has no valid state there.
    """
    return np.unique(challenges.sim_agent_ids(scenario))


# --------------------------------------------------------------------------
# Metadata
# --------------------------------------------------------------------------
def _blank(text: str) -> bool:
    return not text.strip()


def check_metadata(submission: Any, shard: str | None = None) -> list[Finding]:
    """Metadata rules on one shard's `SimAgentsChallengeSubmission`."""
    out: list[Finding] = []

    def missing(field: str, detail: str) -> None:
        out.append(make_finding("metadata.missing", detail, shard=shard, field=field))

    def invalid(field: str, detail: str) -> None:
        out.append(make_finding("metadata.invalid", detail, shard=shard, field=field))

    if not submission.HasField("submission_type"):
        missing("submission_type", "submission_type is not set; it must be SIM_AGENTS_SUBMISSION")
    elif submission.submission_type != SIM_AGENTS_SUBMISSION:
        name = submission.DESCRIPTOR.fields_by_name["submission_type"].enum_type.values_by_number.get(
            submission.submission_type
        )
        shown = name.name if name is not None else str(submission.submission_type)
        invalid("submission_type", f"submission_type is {shown}, expected SIM_AGENTS_SUBMISSION")

    for field in _REQUIRED_TEXT:
        if _blank(getattr(submission, field)):
            missing(field, f"{field} is empty")
    if not _blank(submission.account_name) and "@" not in submission.account_name:
        invalid(
            "account_name",
            f"account_name {submission.account_name!r} is not an email address; it must be the "
            "full email used to register at waymo.com/open",
        )

    if not submission.authors:
        missing("authors", "authors is empty; list at least one author")
    for i, author in enumerate(submission.authors):
        if _blank(author):
            invalid("authors", f"authors[{i}] is empty")

    if _blank(submission.method_link):
        out.append(
            make_finding(
                "metadata.recommended",
                "method_link is empty; a link to a paper or page describing the method is expected",
                shard=shard,
                field="method_link",
                severity=WARNING,
            )
        )

    for field in _REQUIRED_FLAGS:
        if not submission.HasField(field):
            missing(field, f"{field} is not set; it is required (true or false)")
    if submission.uses_public_model_pretraining and not [n for n in submission.public_model_names if not _blank(n)]:
        missing(
            "public_model_names",
            "public_model_names is empty although uses_public_model_pretraining is true; name the models used",
        )

    params = submission.num_model_parameters
    if _blank(params):
        missing("num_model_parameters", "num_model_parameters is empty; give an estimate such as '200K' or '1.5B'")
    elif not _PARAMETER_COUNT.match(params):
        invalid(
            "num_model_parameters",
            f"num_model_parameters {params!r} is not a number with an optional K/M/B/T suffix (e.g. '200K')",
        )

    ack = "acknowledge_complies_with_closed_loop_requirement"
    if not submission.HasField(ack):
        missing(ack, f"{ack} is not set; it must be true (closed-loop simulation at 10 Hz)")
    elif not getattr(submission, ack):
        invalid(ack, f"{ack} is false; it must be true (closed-loop simulation at 10 Hz)")
    return out


def metadata_of(submission: Any) -> dict[str, Any]:
    """The metadata fields of a shard as plain values (None where unset), to compare shards."""
    values: dict[str, Any] = {}
    for field in METADATA_FIELDS:
        value = getattr(submission, field)
        if field in ("authors", "public_model_names"):
            values[field] = tuple(value)
        else:
            values[field] = value if submission.HasField(field) else None
    return values


def check_metadata_consistency(
    reference: dict[str, Any], reference_shard: str, metadata: dict[str, Any], shard: str
) -> list[Finding]:
    """One finding per metadata field whose value in `shard` differs from `reference_shard`."""
    return [
        make_finding(
            "metadata.inconsistent",
            f"{field} is {metadata[field]!r} but {reference[field]!r} in {reference_shard}",
            shard=shard,
            field=field,
        )
        for field in METADATA_FIELDS
        if metadata[field] != reference[field]
    ]


# --------------------------------------------------------------------------
# Coverage
# --------------------------------------------------------------------------
def check_missing_scenarios(expected: Iterable[str], submitted: Iterable[str] | set[str]) -> list[Finding]:
    """One finding per scenario of the scenario set that the submission lacks (in scenario-set order)."""
    submitted = submitted if isinstance(submitted, (set, dict, frozenset)) else set(submitted)
    missing = [sid for sid in expected if sid not in submitted]
    total = len(missing)
    return [
        make_finding(
            "coverage.missing_scenario",
            f"missing from the submission ({total} scenario(s) of the set are missing)",
            scenario_id=sid,
        )
        for sid in missing
    ]


def check_overlap(expected_count: int, submitted_ids: Iterable[str], expected: dict | set) -> list[Finding]:
    """One finding when scenarios were submitted but none is in the scenario set: likely the wrong split."""
    submitted = list(submitted_ids)
    if not submitted or not expected_count or any(sid in expected for sid in submitted):
        return []
    return [
        make_finding(
            "coverage.no_overlap",
            f"none of the {len(submitted)} submitted scenario(s) is in the scenario set of {expected_count} "
            f"(e.g. {submitted[0]}); are --scenarios the split the submission was made for "
            "(validation vs testing)?",
        )
    ]


def unknown_scenario(scenario_id: str, shard: str, index: int) -> Finding:
    return make_finding(
        "coverage.unknown_scenario",
        f"not in the scenario set (scenario_rollouts[{index}])",
        shard=shard,
        scenario_id=scenario_id,
    )


def duplicate_scenario(scenario_id: str, shard: str, index: int, first: tuple[str, int]) -> Finding:
    return make_finding(
        "coverage.duplicate_scenario",
        f"submitted again at scenario_rollouts[{index}]; first in {first[0]} at scenario_rollouts[{first[1]}]",
        shard=shard,
        scenario_id=scenario_id,
    )


def missing_scenario_id(shard: str, index: int) -> Finding:
    return make_finding(
        "coverage.missing_scenario_id",
        f"scenario_rollouts[{index}] has no scenario_id; its rollouts cannot be matched to a scenario",
        shard=shard,
    )


# --------------------------------------------------------------------------
# Rollouts
# --------------------------------------------------------------------------
def _field_checks(rollouts: Any, fields: Sequence[str], n_trajectories: int, spec: challenges.ChallengeSpec):
    """Per trajectory of `rollouts` (in joint-scene order) and field: value counts, non-finite and
    non-positive (finite, <= 0; box sizes only) masks, each shape (num_trajectories, len(fields)); the object
    ids, whether each is set, and whether an object_type is set (not TYPE_UNSET), shape (num_trajectories,);
    and the fields set that the challenge's evaluator does not read (`_ignored_fields`).
    Read from the scenario's serialized bytes at once (`parse.wire_walks`)."""
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
    ignored = _ignored_fields(spec, dict(zip(walked, counts.any(axis=0))), valid_count, valid_false, type_set)
    k = len(fields)
    non_positive = non_positive[:, :k] & np.isin(fields, BOX_FIELDS)
    return counts[:, :k], non_finite[:, :k], non_positive, ids, has_id, object_type != TYPE_UNSET, ignored


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


class _SceneLocation(TypedDict):
    """Where a scene's findings are (`make_finding`'s keywords)."""

    shard: str | None
    scenario_id: str | None
    rollout: int


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

    ids, has_id: the scene's trajectories' object ids and whether each is set, shape (num_trajectories,).
    sim_agent_ids: sorted unique int64 ids, shape (num_sim_agents,), or None when
    the scenario is unknown (then only missing ids and duplicates are checked).
    """
    out: list[Finding] = []
    loc = _SceneLocation(shard=shard, scenario_id=scenario_id, rollout=rollout)
    for k in np.flatnonzero(~has_id).tolist():
        out.append(make_finding("rollouts.missing_object_id", f"simulated_trajectories[{k}] has no object_id", **loc))
    present, multiplicity = np.unique(ids[has_id], return_counts=True)
    repeated = multiplicity > 1
    if repeated.any():
        dup = ", ".join(f"{i} ({m} times)" for i, m in zip(present[repeated].tolist(), multiplicity[repeated].tolist()))
        out.append(
            make_finding(
                "rollouts.duplicate_objects",
                f"object ids simulated more than once: {dup}; the official "
                "validator accepts it but its scorer fails on the scenario (repeated ids)",
                **loc,
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
                    **loc,
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
                    **loc,
                )
            )
    return out


def _trajectory(scenes: list, starts: np.ndarray, k: int):
    """The `k`th trajectory in joint-scene order (its scene found from the scenes' first indices `starts`)."""
    r = int(np.searchsorted(starts, k, side="right")) - 1
    return scenes[r].simulated_trajectories[k - int(starts[r])]


def check_scenario_rollouts(
    rollouts: Any,
    sim_agent_ids: Sequence[int] | np.ndarray | None,
    *,
    shard: str | None = None,
    challenge: Any = challenges.Challenge.SIM_AGENTS,
    n_rollouts: int | None = None,
    n_steps: int | None = None,
    wire_bytes: bytes | memoryview | None = None,
) -> list[Finding]:
    """Rules on one ScenarioRollouts: n_rollouts joint scenes, each with exactly the sim agents, each
    trajectory with n_steps finite values in center_x, center_y, center_z and heading; for a challenge
    whose submissions carry boxes (scenario gen), also n_steps finite positive values in length, width
    and height and an object_type. Fields the challenge ignores are reported once, as a warning.

    sim_agent_ids: ids of the scenario's objects valid at step 10, shape
    (num_sim_agents,); None when the scenario is not in the scenario set.
    All joint scenes are checked together: the trajectories of the scenario
    are flattened to shape (num_trajectories,), `rollout_of` maps each to its
    joint scene, and the checks run on whole arrays.
    wire_bytes: the serialized `rollouts` it was parsed from, when the caller has them (the checks read
    the wire; without them the message is serialized again).
    """
    spec = challenges.spec(challenge)
    n_rollouts = spec.num_rollouts if n_rollouts is None else n_rollouts
    n_steps = spec.num_simulation_steps if n_steps is None else n_steps
    scenario_id = rollouts.scenario_id or None
    out: list[Finding] = []
    scenes = list(rollouts.joint_scenes)
    if len(scenes) != n_rollouts:
        out.append(
            make_finding(
                "rollouts.wrong_count",
                f"found {len(scenes)} joint scenes, expected {n_rollouts}; the official validator refuses it",
                shard=shard,
                scenario_id=scenario_id,
            )
        )
    expected = None if sim_agent_ids is None else np.unique(np.asarray(sim_agent_ids, dtype=np.int64))
    scene_sizes = np.fromiter(
        (len(scene.simulated_trajectories) for scene in scenes), dtype=np.int64, count=len(scenes)
    )
    n = int(scene_sizes.sum())
    rollout_of = np.repeat(np.arange(len(scenes)), scene_sizes)
    starts = np.concatenate([[0], np.cumsum(scene_sizes)])
    fields = TRAJECTORY_FIELDS + (BOX_FIELDS if spec.submits_boxes else ())
    checks = _field_checks(rollouts if wire_bytes is None else wire_bytes, fields, n, spec)
    counts, non_finite, non_positive, ids, has_id, has_type, ignored = checks

    # Object ids. The common case (every scene holds exactly the sim agents) is
    # proven for all scenes at once; only the other scenes are looked at one by one.
    scene_ok = np.zeros(len(scenes), dtype=bool)
    if expected is not None and len(scenes) and (scene_sizes == expected.size).all() and has_id.all():
        per_scene = np.sort(ids.reshape(len(scenes), expected.size), axis=1)
        scene_ok = (per_scene == expected).all(axis=1)
    for r in np.flatnonzero(~scene_ok).tolist():
        span = slice(starts[r], starts[r + 1])
        out.extend(
            check_scene_object_ids(ids[span], has_id[span], expected, shard=shard, scenario_id=scenario_id, rollout=r)
        )

    def where_(k: int) -> dict[str, Any]:
        return {
            "shard": shard,
            "scenario_id": scenario_id,
            "rollout": int(rollout_of[k]),
            "object_id": int(ids[k]) if has_id[k] else None,
        }

    for k, f in np.argwhere(counts != n_steps).tolist():
        field = fields[f]
        out.append(
            make_finding(
                "rollouts.wrong_length",
                _length_detail(int(counts[k, f]), f, n_steps),
                field=field,
                hint=_length_hint(int(counts[k, f]), f, spec),
                **where_(k),
            )
        )
    for k, f in np.argwhere(non_finite).tolist():
        field = fields[f]
        detail = _non_finite_detail(field, getattr(_trajectory(scenes, starts, k), field))
        out.append(
            make_finding(
                "rollouts.non_finite",
                detail + _NON_FINITE_OFFICIAL,
                field=field,
                severity=WARNING,
                hint=_NON_FINITE_HINT,
                **where_(k),
            )
        )
    for k, f in np.argwhere(non_positive).tolist():
        field = fields[f]
        values = np.asarray(getattr(_trajectory(scenes, starts, k), field), dtype=np.float64)
        bad = np.flatnonzero(np.isfinite(values) & (values <= 0))
        detail = f"{field}[{bad[0]}] is {values[bad[0]]:g}"
        if len(bad) > 1:
            detail += f" ({len(bad)} such values, at indices {format_ids(bad.tolist(), 10)})"
        detail += "; a box size is expected to be positive, the official evaluator scores it as given"
        out.append(
            make_finding(
                "rollouts.non_positive_size",
                detail,
                field=field,
                severity=WARNING,
                hint=_NON_POSITIVE_HINT,
                **where_(k),
            )
        )
    if spec.submits_boxes:
        for k in np.flatnonzero(~has_type).tolist():
            out.append(
                make_finding(
                    "rollouts.missing_object_type",
                    "object_type is not set (or TYPE_UNSET); expected the type of the object "
                    f"({', '.join(PROTO_NAMES.values())}), the official evaluator scores it as "
                    "TYPE_UNSET",
                    field="object_type",
                    severity=WARNING,
                    hint=_MISSING_TYPE_HINT,
                    **where_(k),
                )
            )
    if ignored:
        out.append(
            make_finding(
                "rollouts.ignored_field",
                f"fields {', '.join(ignored)} are set but ignored: {_IGNORED_WHY[spec.submits_boxes]}",
                shard=shard,
                scenario_id=scenario_id,
                field=ignored[0],
                severity=WARNING,
            )
        )
    return out
