"""Errors raised while turning bytes (files, archives, records) into messages.

Every error is a `ParseError`, itself a `ValueError`, so callers can catch
all "this input is bad" failures with one clause and report the message:
each message names the file, archive member or shard and, where it applies,
the byte offset at fault.
"""

from __future__ import annotations


class ParseError(ValueError):
    """Input bytes or paths that cannot be read as what they claim to be."""


class CorruptRecordError(ParseError):
    """A TFRecord whose framing is truncated or fails its CRC32C check."""

    def __init__(self, path: object, offset: int, problem: str) -> None:
        self.path = str(path)
        self.offset = offset
        self.problem = problem
        super().__init__(f"{path}: corrupt TFRecord at byte offset {offset}: {problem}")


class ScenarioPathError(ParseError):
    """A scenario path, folder or glob that names no file."""


class DuplicateScenarioError(ParseError):
    """The same scenario_id found at two places in the scenario shards."""


class UnknownScenarioError(ParseError, KeyError):
    """A scenario_id asked of a ScenarioIndex that holds no such scenario."""

    def __str__(self) -> str:  # KeyError would repr() the message otherwise
        return str(self.args[0])


class ArchiveError(ParseError):
    """A submission archive that is truncated, malformed or not an archive.

    shard: the shard (file of a folder) it is about, when the message names one.
    """

    def __init__(self, message: str, *, shard: str | None = None) -> None:
        super().__init__(message)
        self.shard = shard


class UnsafeArchiveMemberError(ArchiveError):
    """An archive member that could escape extraction or is not a plain file."""


class SizeLimitError(ArchiveError):
    """A member, or the archive as a whole, decompresses past the size limit."""


class InvalidShardError(ParseError):
    """Shard bytes that are not a valid SimAgentsChallengeSubmission."""
