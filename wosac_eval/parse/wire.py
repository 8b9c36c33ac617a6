"""Reading protobuf messages straight from the wire, where a full parse would cost more.

- `packed_coordinates`: the packed coordinates of `SimulatedTrajectory` messages;
- `record_runs`: repeated small submessages (track states, map points) as fixed-size records;
- `field_spans`: where each occurrence of a length-delimited field sits in a message.

Packed coordinates:

Protobuf serialises a parsed message canonically (known fields in field-number
order, each packed field as one block), so a trajectory whose `center_x`,
`center_y`, `center_z` and `heading` (fields 2 to 5) hold `num_steps` values
each serialises to bytes that start with four blocks "tag, length, values".
Stacking those prefixes gives every trajectory's coordinates as one float32
array without a Python loop over values; trajectories laid out otherwise are
reported as irregular, for a field-by-field fallback.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

COORDINATE_FIELDS = ("center_x", "center_y", "center_z", "heading")


def varint(value: int) -> bytes:
    """Protobuf base-128 varint of a non-negative integer."""
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def packed_headers(num_steps: int, field_numbers=(2, 3, 4, 5)) -> np.ndarray:
    """Wire headers (tag, byte length) of packed float fields with `num_steps` values each, uint8 `(fields, header)`."""
    length = varint(4 * num_steps)
    return np.array([[(number << 3) | 2, *length] for number in field_numbers], dtype=np.uint8)


def _packed_blocks(data: list[bytes], starts: np.ndarray, field_numbers, num_steps: int):
    """Consecutive packed float fields at `starts[i]` of `data[i]`: (regular, float32 `(num_regular, fields, num_steps)`)."""
    n = len(data)
    headers = packed_headers(num_steps, field_numbers)
    block = headers.shape[1] + 4 * num_steps
    size = len(field_numbers) * block
    heads = [d[s:s + size] for d, s in zip(data, starts.tolist())]
    long_enough = (np.fromiter(map(len, heads), dtype=np.int64, count=n) == size) & (starts >= 0)
    if not long_enough.all():
        heads = [h.ljust(size, b"\0")[:size] for h in heads]
    stacked = np.frombuffer(b"".join(heads), dtype=np.uint8).reshape(n, len(field_numbers), block)
    regular = long_enough & (stacked[:, :, : headers.shape[1]] == headers).all(axis=(1, 2))
    values = np.ascontiguousarray(stacked[regular, :, headers.shape[1]:]).view("<f4").astype(np.float32)
    return regular, values


def packed_coordinates(trajectories: Sequence, num_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Coordinates of the regularly laid out trajectories.

    Args:
      trajectories: `SimulatedTrajectory` messages (or their wire bytes).
      num_steps: the expected number of values per field.
    Returns:
      (regular, values): bool `(num_trajectories,)`, True where the four fields
      hold exactly `num_steps` values in canonical layout; float32
      `(num_regular, 4, num_steps)` for those, fields in `COORDINATE_FIELDS` order.
    """
    prefix = 4 * (packed_headers(num_steps).shape[1] + 4 * num_steps)
    heads = [d[:prefix] for d in serialized(trajectories)]
    return _packed_blocks(heads, np.zeros(len(heads), np.int64), (2, 3, 4, 5), num_steps)


def serialized(messages: Sequence) -> list[bytes]:
    """The wire bytes of each message (bytes are taken as they are)."""
    return [m if isinstance(m, bytes) else m.SerializeToString() for m in messages]


BOX_FIELDS = ("length", "width", "height")
_BOX_FIELD_NUMBERS = (7, 8, 9)  # width, length, height on the wire
_OBJECT_ID_TAG, _OBJECT_TYPE_TAG = (6 << 3), (10 << 3)


def packed_boxes(trajectories: Sequence, num_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-step box sizes and the object type of regularly laid out trajectories (scenario gen).

    A canonical trajectory with every field set serialises as the four
    coordinate blocks, the `object_id` varint, the width / length / height
    blocks and the `object_type` varint; the position of the size blocks
    depends only on the length of the id's varint, so trajectories are read
    with one gather per distinct length.

    Args:
      trajectories: `SimulatedTrajectory` messages (or their wire bytes).
    Returns:
      (regular, sizes, object_type): bool `(num_trajectories,)`; float32
      `(num_regular, 3, num_steps)` in `BOX_FIELDS` order; int32 `(num_regular,)`.
    """
    n = len(trajectories)
    data = serialized(trajectories)
    prefix = 4 * (packed_headers(num_steps).shape[1] + 4 * num_steps)
    # The id's varint: at most 10 bytes after its tag.
    window = np.frombuffer(b"".join(d[prefix:prefix + 11].ljust(11, b"\0") for d in data), np.uint8).reshape(n, 11)
    ends = np.argmax(window[:, 1:] < 0x80, axis=1)  # index of the varint's last byte
    has_id = (window[:, 0] == _OBJECT_ID_TAG) & (window[:, 1:] < 0x80).any(axis=1)
    starts = np.where(has_id, prefix + 2 + ends, -1)
    block = packed_headers(num_steps).shape[1] + 4 * num_steps
    type_at = np.where(starts >= 0, starts + 3 * block, 0)
    type_bytes = np.frombuffer(b"".join(d[s:s + 2].ljust(2, b"\0") for d, s in zip(data, type_at.tolist())),
                               np.uint8).reshape(n, 2)
    has_type = (type_bytes[:, 0] == _OBJECT_TYPE_TAG) & (type_bytes[:, 1] < 0x80)
    regular, sizes = _packed_blocks(data, np.where(has_type, starts, -1), _BOX_FIELD_NUMBERS, num_steps)
    # width, length on the wire; length, width here.
    sizes = sizes[:, [1, 0, 2]]
    return regular, sizes, type_bytes[regular, 1].astype(np.int32)


_SIZE = {"d": 8, "f": 4, "b": 1}
_WIRE_TYPE = {"d": 1, "f": 5, "b": 0}


def record_run(data: bytes, field_number: int, layout: Sequence[tuple[int, str]], count: int) -> np.ndarray | None:
    """`record_runs` for one parent message: float64 `(count, len(layout))`, or None."""
    values, regular = record_runs([data], field_number, layout, [count])
    return values[0] if regular[0] else None


def _run_segments(data: bytes, field_number: int, count: int) -> list | None:
    """The run's records as (offset, record size, number of records) segments of equal size.

    None if the run is not laid out as expected. Records are located by
    following their length bytes; equal-size neighbours are checked together
    with strided byte slices, so a run costs a few operations per change of
    record size, not per record.
    """
    tag = (field_number << 3) | 2
    pos, end = 0, len(data)
    # Skip the (few) lower-numbered fields in front of the run.
    while pos < end and data[pos] != tag:
        key = data[pos]
        if key & 0x80 or (key >> 3) >= field_number:
            return None
        pos = skip_field(data, pos + 1, key & 7)
    segments, remaining = [], count
    while remaining:
        if pos + 2 > end or data[pos] != tag or data[pos + 1] & 0x80:
            return None
        size = 2 + data[pos + 1]
        stop = pos + size * remaining
        # Record k of the segment is aligned if record k - 1 was and had this size.
        heads, lengths = data[pos:stop:size], data[pos + 1:stop:size]
        n = min(len(heads) - len(heads.lstrip(bytes((tag,)))),
                len(lengths) - len(lengths.lstrip(bytes((size - 2,)))))
        if pos + size * n > end:
            return None
        segments.append((pos, size, n))
        pos += size * n
        remaining -= n
    return segments


def record_runs(parents: Sequence[bytes], field_number: int, layout: Sequence[tuple[int, str]],
                counts: Sequence[int]) -> tuple[list, np.ndarray]:
    """The elements of a repeated field of many serialised parents, read straight from the wire.

    A parsed message serialises canonically: fields in number order, the
    elements of a repeated field back to back. When an element holds a subset
    of the scalar fields in `layout` ((field number, "d" double | "f" float |
    "b" bool) pairs) it is a small fixed-layout record; records are grouped by
    size and each group is read with one numpy gather. Fields an element does
    not hold read as 0 (their proto2 default). A parent laid out otherwise (an
    unknown field, a multi-byte tag or length) is reported irregular, for a
    field-by-field fallback.

    Args:
      parents: serialised parent messages.
      field_number: the repeated field (at most 15).
      counts: its number of elements in each parent.
    Returns:
      (values, regular): per parent, float64 `(count, len(layout))` (None
      where irregular); bool `(num_parents,)`.
    """
    regular = np.zeros(len(parents), bool)
    values: list = [None] * len(parents)
    if field_number > 15 or any(number > 15 for number, _ in layout):
        return values, regular
    bases = np.cumsum([0] + [len(p) for p in parents])
    segments, first_row, rows = [], np.zeros(len(parents), np.int64), 0
    for i, (data, count) in enumerate(zip(parents, counts)):
        found = _run_segments(data, field_number, count) if count else []
        regular[i] = found is not None
        first_row[i] = rows
        if found is not None:
            rows += count
            segments.extend((int(bases[i]) + offset, size, n, i) for offset, size, n in found)
    buffer = np.frombuffer(b"".join(parents), np.uint8)
    offset, size, n, parent = np.array(segments, np.int64).reshape(-1, 4).T
    # Expand the segments to one start (and one record size) per record.
    within = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    sizes = np.repeat(size, n)
    starts = np.repeat(offset, n) + sizes * within
    owner = np.repeat(parent, n)
    out = np.zeros((len(starts), len(layout)), np.float64)
    for record in np.unique(sizes):
        group = np.flatnonzero(sizes == record)
        if not _read_group(buffer, starts[group], int(record), layout, out, group):
            # Records of one size laid out unlike the first one: their parents are irregular.
            regular[owner[group]] = False
    for i in np.flatnonzero(regular):
        values[i] = out[first_row[i]:first_row[i] + counts[i]]
    return values, regular


def _read_group(buffer: np.ndarray, starts: np.ndarray, record: int, layout, out: np.ndarray,
                rows_out: np.ndarray) -> bool:
    """Records of one size, whose fields must sit at the same offsets as in the first one."""
    first = bytes(buffer[starts[0]:starts[0] + record])
    fields, offset = [], 2
    kinds = dict(layout)
    while offset < record:
        key = first[offset]
        number, wire_type = key >> 3, key & 7
        kind = kinds.get(number)
        if key & 0x80 or kind is None or _WIRE_TYPE[kind] != wire_type or (fields and number <= fields[-1][0]):
            return False
        fields.append((number, offset))
        offset += 1 + _SIZE[kind]
    if offset != record:
        return False
    rows = buffer[starts[:, None] + np.arange(record)]
    checks = [0, 1] + [o for _, o in fields]
    if not (rows[:, checks] == rows[0, checks]).all():
        return False
    column = {number: j for j, (number, _) in enumerate(layout)}
    for number, o in fields:
        kind = kinds[number]
        raw = np.ascontiguousarray(rows[:, o + 1:o + 1 + _SIZE[kind]])
        if kind == "b":
            if (raw > 1).any():
                return False
            out[rows_out, column[number]] = raw[:, 0]
        else:
            out[rows_out, column[number]] = raw.view("<f8" if kind == "d" else "<f4")[:, 0]
    return True


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
