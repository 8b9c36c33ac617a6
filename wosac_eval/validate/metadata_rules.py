"""Metadata rules: one shard's `SimAgentsChallengeSubmission` fields as the challenge server requires
them, and the same metadata in every shard.

Local scoring needs none of it (`scoring` grades these findings as warnings unless asked otherwise);
`wosac-eval validate` and the service apply them as the challenge server does.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

from wosac_eval.validate.findings import WARNING, Finding, Location, make_finding

if TYPE_CHECKING:  # the messages checked; the checks read their fields and need no import of the classes
    from wosac_eval.protos.sim_agents_submission_pb2 import SimAgentsChallengeSubmission

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


def _blank(text: str) -> bool:
    return not text.strip()


def check_metadata(submission: SimAgentsChallengeSubmission, shard: str | None = None) -> list[Finding]:
    """Metadata rules on one shard's `SimAgentsChallengeSubmission`."""
    out: list[Finding] = []

    def missing(field: str, detail: str) -> None:
        out.append(make_finding("metadata.missing", detail, Location(shard), field=field))

    def invalid(field: str, detail: str) -> None:
        out.append(make_finding("metadata.invalid", detail, Location(shard), field=field))

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
                Location(shard),
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


def metadata_of(submission: SimAgentsChallengeSubmission) -> dict[str, Any]:
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
            Location(shard),
            field=field,
        )
        for field in METADATA_FIELDS
        if metadata[field] != reference[field]
    ]
