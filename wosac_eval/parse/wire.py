"""Reading protobuf messages straight from the wire, where a full parse would cost more (Python side).

- `field_spans`: where each occurrence of a length-delimited field sits in one message, to split a
  large submission without parsing it;
- `varint`, `packed_headers`: writing the wire format (`arrays.messages`);
- the field numbers of `SimulatedTrajectory` the readers use.

The compiled walks over whole messages (numba) are in `parse.wire_walks`, imported only where used:
this module stays light for the processes that only split or check files.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

COORDINATE_FIELDS = ("center_x", "center_y", "center_z", "heading")
BOX_FIELDS = ("length", "width", "height")
# SimulatedTrajectory field numbers of COORDINATE_FIELDS and BOX_FIELDS (width is 7, length 8 on the wire).
TRAJECTORY_FIELD_NUMBERS = {
    "center_x": 2,
    "center_y": 3,
    "center_z": 4,
    "heading": 5,
    "length": 8,
    "width": 7,
    "height": 9,
}
VALID_FIELD_NUMBER = 11  # SimulatedTrajectory.valid, a repeated bool


def varint(value: int) -> bytes:
    """Protobuf base-128 varint of a non-negative integer."""
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def packed_headers(num_steps: int, field_numbers: Iterable[int] = (2, 3, 4, 5)) -> np.ndarray:
    """Wire headers (tag, byte length) of packed float fields with `num_steps` values each, uint8
    `(num_fields, num_bytes)`."""
    length = varint(4 * num_steps)
    return np.array([[(number << 3) | 2, *length] for number in field_numbers], dtype=np.uint8)


def read_varint(data: bytes, pos: int) -> tuple[int, int]:
    """(value, next offset) of the base-128 varint at `pos`; ValueError if truncated or overlong."""
    value, shift = 0, 0
    while True:
        if pos >= len(data) or shift > 63:
            raise ValueError("truncated or overlong varint")
        byte = data[pos]
        value |= (byte & 0x7F) << shift
        pos, shift = pos + 1, shift + 7
        if not byte & 0x80:
            return value, pos


def skip_field(data: bytes, pos: int, wire_type: int) -> int:
    """Offset just past the value of a field whose tag ended at `pos`."""
    if wire_type == 0:
        return read_varint(data, pos)[1]
    if wire_type == 1:
        return pos + 8
    if wire_type == 5:
        return pos + 4
    if wire_type == 2:
        length, pos = read_varint(data, pos)
        return pos + length
    raise ValueError(f"unsupported wire type {wire_type}")


def field_spans(data: bytes, field_number: int) -> list[tuple[int, int]]:
    """(start, end) of the value of every occurrence of a length-delimited field.

    Walks the top level of a serialised message, skipping other fields by
    their wire type, so a large message is split without being parsed.

    Raises:
      ValueError: the bytes are not a well-formed message at the top level.
    """
    spans, pos, end = [], 0, len(data)
    while pos < end:
        key, pos = read_varint(data, pos)
        number, wire_type = key >> 3, key & 7
        if number == 0:
            raise ValueError("field number 0")
        field_end = skip_field(data, pos, wire_type)
        if field_end > end:
            raise ValueError("last field runs past the end of the message")
        if number == field_number and wire_type == 2:
            spans.append((read_varint(data, pos)[1], field_end))
        pos = field_end
    return spans
