"""Shard bytes -> messages: what a submission shard holds, read from its bytes.

`parse_submission_shard` parses one shard (its messages counted on the wire
first, against `InputLimits`); `split_shard` cuts a shard into its scenarios'
serialized `ScenarioRollouts` without parsing them; `looks_like_submission`
tells from a shard's first bytes whether it can be one at all (the upload
check asks it of every member).
"""
from __future__ import annotations

from google.protobuf.message import DecodeError

from wosac_eval.parse.decode import decode_message
from wosac_eval.parse.errors import ArchiveError, InvalidShardError, ParseError
from wosac_eval.parse.limits import InputLimits, check_message_counts
from wosac_eval.parse.tar_format import BLOCK, is_tar_header
from wosac_eval.parse.tfrecord import looks_like_tfrecord
from wosac_eval.parse.wire import field_spans, read_varint
from wosac_eval.protos import sim_agents_submission_pb2

# What a shard's first field may be: (field number, wire type) of SimAgentsChallengeSubmission.
_SUBMISSION_FIELDS = {1: 2, 2: 0, 3: 2, 4: 2, 5: 2, 6: 2, 7: 2, 8: 2, 9: 0, 10: 0, 11: 0, 12: 2, 13: 2, 14: 0}
HEAD_BYTES = 16  # the first bytes `looks_like_submission` judges
_FOREIGN_FORMATS = (
    (b"{", "JSON"), (b"[", "JSON"), (b"\x89PNG", "a PNG image"), (b"\xff\xd8\xff", "a JPEG image"),
    (b"GIF8", "a GIF image"), (b"%PDF", "a PDF document"), (b"<", "HTML or XML"), (b"PK\x03\x04", "a zip archive"),
)


class NotASubmissionError(ArchiveError):
    """Bytes of another kind of file (JSON, an image, text...) given as a submission."""


def looks_like_submission(where: str, head: bytes) -> None:
    """Raise NotASubmissionError unless `head` can start a serialized SimAgentsChallengeSubmission
    (its first field is one of the message's, with the right wire type); empty bytes pass."""
    if not head:
        return
    try:
        key, _ = read_varint(head, 0)
        ok = _SUBMISSION_FIELDS.get(key >> 3) == key & 7
    except ValueError:
        ok = False
    if ok:
        return
    kind = next((name for magic, name in _FOREIGN_FORMATS if head.lstrip()[:len(magic)] == magic), None)
    detail = f"it looks like {kind}" if kind else f"its first bytes are {head[:8]!r}"
    raise NotASubmissionError(
        f"{where}: not a SimAgentsChallengeSubmission shard ({detail}); submit a .tar.gz of .binproto "
        "shards or one .binproto"
    )


def string_fields_are_text(
    submission: sim_agents_submission_pb2.SimAgentsChallengeSubmission,
) -> str | None:
    """The first string field holding invalid UTF-8, as 'field (index)', else None.

    proto2 strings are not UTF-8-checked when parsing; the Python runtime
    then hands back bytes instead of str, which must not reach later stages.
    """
    for field in (
        "account_name",
        "unique_method_name",
        "affiliation",
        "description",
        "method_link",
        "num_model_parameters",
    ):
        if not isinstance(getattr(submission, field), str):
            return field
    for field in ("authors", "public_model_names"):
        for index, value in enumerate(getattr(submission, field)):
            if not isinstance(value, str):
                return f"{field}[{index}]"
    for index, rollouts in enumerate(submission.scenario_rollouts):
        if not isinstance(rollouts.scenario_id, str):
            return f"scenario_rollouts[{index}].scenario_id"
    return None


def _why_unparseable(raw: bytes) -> str:
    """A hint at why bytes do not parse: a cut-short file, or another kind of file."""
    if raw[:2] == b"\x1f\x8b" or is_tar_header(raw[:BLOCK]):
        return " (these are archive bytes: give the archive itself as the submission)"
    if looks_like_tfrecord(raw):
        return " (this is a TFRecord file, as scenarios come: are --scenarios and --submission swapped?)"
    try:
        field_spans(raw, 1)
    except ValueError as error:
        if "past the end" in str(error) or "truncated" in str(error):
            return (" (the shard is truncated: its last field runs past the end of the data; was the file "
                    "cut short by an interrupted copy or upload?)")
    return ""


def parse_submission_shard(
    name: str, raw: bytes, limits: InputLimits | None = None
) -> sim_agents_submission_pb2.SimAgentsChallengeSubmission:
    """Parse one shard's bytes, raising InvalidShardError naming the shard if invalid, SizeLimitError
    when it holds more messages than `limits` allow (counted on the wire first)."""
    check_message_counts(name, raw, limits)
    try:
        submission = decode_message(sim_agents_submission_pb2.SimAgentsChallengeSubmission, raw)
    except DecodeError as error:
        raise InvalidShardError(
            f"shard {name}: not a valid SimAgentsChallengeSubmission message "
            f"({len(raw)} bytes): {error}{_why_unparseable(raw)}"
        ) from error
    bad_field = string_fields_are_text(submission)
    if bad_field is not None:
        raise InvalidShardError(f"shard {name}: field {bad_field} is not valid UTF-8 text")
    return submission


def split_shard(name: str, raw: bytes, limits: InputLimits | None = None) -> list[tuple[str, bytes]]:
    """(scenario_id, serialized ScenarioRollouts) of every scenario of a shard.

    The shard is split at the wire level (`field_spans`: scenario_rollouts is
    field 1 of the submission, scenario_id field 1 of each element), so the
    parent process hands the workers bytes without parsing and re-serialising
    them; anything unexpected falls back to a full parse.
    """
    check_message_counts(name, raw, limits)
    try:
        items = []
        for start, end in field_spans(raw, 1):
            data = raw[start:end]
            ids = field_spans(data, 1)  # a repeated singular field: the last one counts, as in a parse
            items.append((data[ids[-1][0]:ids[-1][1]].decode("utf-8") if ids else "", data))
        return items
    except (ValueError, UnicodeDecodeError):
        try:
            submission = parse_submission_shard(name, raw, limits)
        except ParseError:
            return []
        return [(r.scenario_id, r.SerializeToString()) for r in submission.scenario_rollouts]

