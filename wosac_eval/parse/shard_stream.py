"""A submission shard read one top-level field at a time, never whole.

An official shard is 300-700 MB: parsed whole, it costs its size twice or more in
one process. Its top level is a sequence of fields (scenario_rollouts, field 1, one
per scenario, then the metadata), so it can be read field by field from its file:
`iter_top_level_fields` gives each field's bytes in turn, a scenario's at most at
once. It accepts only a plainly well-formed top level (tags of field numbers 1 to
2**29 - 1 with wire types 0, 1, 2 or 5, varints of at most 9 bytes, lengths within
the shard); anything else raises `IrregularShard`, and the reader then judges the
shard whole, as before, so that every message about a malformed shard is unchanged.
"""

from __future__ import annotations

import io
from collections.abc import Iterator
from typing import IO

_MAX_VARINT_BYTES = 9  # 63 bits: every regular tag and length; a 10-byte varint goes to the whole parse
_MAX_FIELD_NUMBER = (1 << 29) - 1
_MAX_LENGTH = (1 << 31) - 1  # the protobuf runtime's bound on one length-delimited value


class IrregularShard(ValueError):
    """The shard's top level is not plainly well-formed (or its file is shorter than said): judge it whole."""


def _varint(f: IO[bytes], left: int) -> tuple[int, bytes]:
    """(value, its bytes) of the varint at the file's position, within `left` bytes of the shard."""
    value, raw = 0, bytearray()
    while True:
        if len(raw) >= min(left, _MAX_VARINT_BYTES):
            raise IrregularShard("truncated or overlong varint")
        byte = f.read(1)
        if not byte:
            raise IrregularShard("the file ends inside the shard")
        raw += byte
        value |= (byte[0] & 0x7F) << (7 * (len(raw) - 1))
        if not byte[0] & 0x80:
            return value, bytes(raw)


def _exactly(f: IO[bytes], size: int) -> bytes:
    data = f.read(size)
    if len(data) != size:
        raise IrregularShard("the file ends inside the shard")
    return data


def iter_top_level_fields(f: IO[bytes], size: int) -> Iterator[tuple[int, int, bytes, int, int]]:
    """(field number, wire type, the field's bytes, start, end) of every top-level field of the `size`-byte
    shard at the (seekable) file's position, in order. The field's bytes are its tag, length and value (they parse as a
    message of the shard's type holding that field alone); its value is bytes[start:end].

    Raises:
      IrregularShard: as soon as the top level is not plainly well-formed (see the module).
    """
    at = 0
    while at < size:
        key, tag = _varint(f, size - at)
        number, wire_type = key >> 3, key & 7
        if not 1 <= number <= _MAX_FIELD_NUMBER or key >> 32:
            raise IrregularShard(f"tag {key}")
        if wire_type == 0:
            _, value = _varint(f, size - at - len(tag))
            head, length = tag, len(value)
            field = tag + value
        elif wire_type in (1, 5):
            head, length = tag, 8 if wire_type == 1 else 4
            if length > size - at - len(tag):
                raise IrregularShard("a fixed-size field runs past the end")
            field = tag + _exactly(f, length)
        elif wire_type == 2:
            length, prefix = _varint(f, size - at - len(tag))
            head = tag + prefix
            if length > _MAX_LENGTH or length > size - at - len(head):
                raise IrregularShard("a field runs past the end")
            f.seek(-len(head), io.SEEK_CUR)  # the head read again with its value: one read, no join of the two
            field = _exactly(f, len(head) + length)
        else:
            raise IrregularShard(f"wire type {wire_type}")
        yield number, wire_type, field, len(head), len(field)
        at += len(field)
