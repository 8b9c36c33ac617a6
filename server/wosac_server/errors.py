"""The service's refusals, as the rules name them: what the service layer raises, whatever the transport.

Each kind is a reason a request is refused (a key unknown, a quota spent, the disk full, an upload
busy); one sentence (`detail`) says why to the person who sent it. The service layer raises these and
nothing HTTP; `routes.answers` is the one place that maps each kind to its status code and headers.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class UploadPosition:
    """Where a resumable upload stands, told with a refusal of it (so a client resumes from there)."""

    offset: int
    length: int | None


class ServiceError(Exception):
    """A request the service refuses: `detail` says why; `retry_after_s` when it may pass by itself;
    `upload` when it concerns a resumable upload whose position the client needs."""

    def __init__(self, detail: str, *, retry_after_s: int | None = None, upload: UploadPosition | None = None):
        super().__init__(detail)
        self.detail = detail
        self.retry_after_s = retry_after_s
        self.upload = upload


class BadRequest(ServiceError):
    """The request itself is malformed (a header that does not parse, a body cut short)."""


class Unauthenticated(ServiceError):
    """No key, or one the service does not know (revoked, mistyped)."""

    def __init__(self, detail: str, *, sent_a_key: bool):
        super().__init__(detail)
        self.sent_a_key = sent_a_key


class NotOwner(ServiceError):
    """A leaderboard name that another key owns."""


class NotFound(ServiceError):
    """No such thing for this key (another key's ids are not even confirmed to exist)."""


class Conflict(ServiceError):
    """Not now: results not ready, an upload at another offset, another request at work on it."""


class Gone(ServiceError):
    """Stored bytes or files that are no longer on the server's disk (or damaged)."""


class VersionUnsupported(ServiceError):
    """A protocol version the service does not speak (tus's `Tus-Resumable`)."""


class TooLarge(ServiceError):
    """Past a size limit: the server's, one request's, or the key's day's bytes."""


class NotASubmission(ServiceError):
    """Bytes that are no submission at all (JSON, an image, a form), or sent in the wrong form."""


class Invalid(ServiceError):
    """A parameter out of range, or a submission that cannot be read (truncated, unsafe, past a limit)."""


class TooMany(ServiceError):
    """A quota of the key (job slots, submissions a day, open uploads) or of its address (failed keys)."""


class ChecksumMismatch(ServiceError):
    """A chunk whose bytes do not match the checksum sent with it (tus's checksum extension)."""


class NoSpace(ServiceError):
    """The data dir's disk is full, or would be past its floor with this upload."""
