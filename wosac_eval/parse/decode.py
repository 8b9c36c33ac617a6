"""One protobuf message from its bytes, telling a refused allocation from damaged bytes.

The protobuf runtime (upb) reports an allocation refused under an address-space limit
(RLIMIT_AS: the service's WOSAC_JOB_MEMORY_BYTES, or a user's `ulimit -v`) as a DecodeError,
the same error as for damaged bytes: a valid record would be reported as corrupt.
"""

from __future__ import annotations

import resource
from typing import TypeVar

from google.protobuf.message import DecodeError, Message

M = TypeVar("M", bound=Message)


def decode_message(message_class: type[M], data: bytes) -> M:
    """`message_class` parsed from `data`: DecodeError if the bytes are not one, MemoryError if
    the process's memory limit refused the parse.

    Where the soft address-space limit is below the hard one (how the service limits a job), a
    failed parse is tried once more with the soft limit lifted to the hard one; a success then
    means the limit was the cause. The limit is put back either way.
    """
    try:
        return message_class.FromString(data)
    except DecodeError:
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        if soft == resource.RLIM_INFINITY or soft == hard:
            raise
        resource.setrlimit(resource.RLIMIT_AS, (hard, hard))
        try:
            message_class.FromString(data)  # damaged bytes raise their DecodeError here, limit or not
        finally:
            resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
        raise MemoryError(
            f"parsing a {message_class.DESCRIPTOR.name} message of {len(data)} bytes needed more "
            f"memory than the process's address-space limit of {soft} bytes allows"
        ) from None
