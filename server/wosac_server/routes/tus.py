"""tus 1.0.0's headers read into the service's terms: the version asked for, `Upload-Metadata` (the
submission's parameters), `Upload-Checksum`, and the discovery headers `OPTIONS` answers.

Metadata keys (each value base64, as the protocol has it): `challenge`, `config`, `method`, `publish`,
`partial` (the query parameters' names; `allow_partial` is taken too) and `filename` (kept for the
client, never used as a path). Other keys that clients add by themselves (`filetype`, `name`, `type`,
`relativePath`...) are kept and ignored.
"""

from __future__ import annotations

import base64
import binascii
import re
from typing import Annotated

from fastapi import Header

from ..auth import METHOD_PATTERN
from ..errors import BadRequest, Invalid, VersionUnsupported
from ..jobs import SubmissionParams
from ..resumable import MAX_METADATA_CHARS
from ..uploads import CHECKSUMS
from .answers import TUS_VERSION

EXTENSIONS = "creation,termination,expiration,checksum"
CHALLENGES = ("sim_agents", "scenario_gen")
_KEY = re.compile(r"^[!-+\--~]+$")  # printable ASCII without space or comma
_TRUE, _FALSE = ("true", "1", "yes", "on"), ("false", "0", "no", "off", "")


def speaks_tus(tus_resumable: Annotated[str | None, Header()] = None) -> bool:
    """Whether the request speaks tus (it sends `Tus-Resumable`); 412 for a version this server does not
    speak. Requests without it are the earlier form of the same resource, still served."""
    if tus_resumable is not None and tus_resumable.strip() != TUS_VERSION:
        raise VersionUnsupported(f"Tus-Resumable {tus_resumable!r}: this server speaks tus {TUS_VERSION}")
    return tus_resumable is not None


def discovery_headers(max_size: int) -> dict[str, str]:
    """What `OPTIONS` tells a client about this server's tus."""
    return {
        "Tus-Resumable": TUS_VERSION,
        "Tus-Version": TUS_VERSION,
        "Tus-Extension": EXTENSIONS,
        "Tus-Max-Size": str(max_size),
        "Tus-Checksum-Algorithm": ",".join(CHECKSUMS),
    }


def parse_metadata(header: str) -> dict[str, str]:
    """`Upload-Metadata` ("key base64, key2 base64, flag") as a dict; `BadRequest` when it does not parse."""
    if len(header) > MAX_METADATA_CHARS:
        raise BadRequest(f"Upload-Metadata is longer than {MAX_METADATA_CHARS} characters")
    pairs: dict[str, str] = {}
    for item in header.split(","):
        if not item.strip():
            continue
        key, _, encoded = item.strip().partition(" ")
        if not _KEY.match(key) or key in pairs:
            raise BadRequest(
                f"Upload-Metadata: {key!r} is not a key (printable ASCII, no space or comma) or comes twice"
            )
        try:
            pairs[key] = base64.b64decode(encoded.strip(), validate=True).decode("utf-8")
        except (binascii.Error, UnicodeDecodeError):
            raise BadRequest(f"Upload-Metadata: the value of {key!r} is not base64 of UTF-8 text") from None
    return pairs


def _flag(metadata: dict[str, str], names: tuple[str, ...], default: bool) -> bool:
    for name in names:
        if name in metadata:
            value = metadata[name].strip().lower()
            if value not in _TRUE + _FALSE:
                raise Invalid(f"Upload-Metadata {name}: {metadata[name]!r} is not true or false")
            return value in _TRUE
    return default


def submission_params(metadata: dict[str, str], query: SubmissionParams) -> SubmissionParams:
    """The submission's parameters: from the metadata, else from the query (the earlier form's)."""
    challenge = metadata.get("challenge", query.challenge)
    if challenge not in CHALLENGES:
        raise Invalid(f"Upload-Metadata challenge: {challenge!r}; choose {' or '.join(CHALLENGES)}")
    method = metadata.get("method", query.method)
    if method is not None and not re.match(METHOD_PATTERN, method):
        raise Invalid(f"Upload-Metadata method: {method!r} does not match {METHOD_PATTERN}")
    return SubmissionParams(
        challenge=challenge,
        config=metadata.get("config") or query.config,
        method=method,
        publish=_flag(metadata, ("publish",), query.publish),
        allow_partial=_flag(metadata, ("partial", "allow_partial"), query.allow_partial),
    )


def parse_checksum(header: str) -> tuple[str, bytes]:
    """`Upload-Checksum` ("sha1 base64-digest") as (algorithm, digest); `BadRequest` for an algorithm this
    server does not compute, or a digest that is not base64."""
    algorithm, _, encoded = header.strip().partition(" ")
    if algorithm.lower() not in CHECKSUMS:
        raise BadRequest(f"Upload-Checksum: algorithm {algorithm!r} is not one of {', '.join(CHECKSUMS)}")
    try:
        return algorithm.lower(), base64.b64decode(encoded.strip(), validate=True)
    except binascii.Error:
        raise BadRequest("Upload-Checksum: the digest is not base64") from None
