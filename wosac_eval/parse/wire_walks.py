"""Compiled walks (numba) over the bytes of a whole protobuf message, for the arrays of a scenario and its rollouts.

- `message_spans`: the submessages of a field in many parents at once;
- `scalar_fields`: the scalar fields of many small records (track states, map points);
- `float_fields`: repeated float fields (the coordinates and box sizes of simulated trajectories);
- `bool_fields`: a repeated bool field's count and whether any value is false (a trajectory's `valid`);
- `rollouts_census`: the messages of a `ScenarioRollouts` counted against the input limits (`parse.limits`).

The walks follow the protobuf encoding rules as a parse does: fields in any order, a field whose wire
type does not match its declaration is an unknown field (skipped), the last occurrence of a scalar
wins, a repeated float may be packed or not, an unset field reads as its default (0), a closed
enum's value out of range is an unknown field. They read the bytes a message was parsed from, or its
serialisation (`message_bytes`); malformed bytes raise ValueError (but in `rollouts_census`, which counts
before any parse: there they end a level's walk). Compiled once per installation
and cached on disk by numba, like the search loops (`scoring.warm_up.compile_loops` compiles both).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numba
import numpy as np

from wosac_eval.parse.wire import varint

if TYPE_CHECKING:  # the walks read bytes; protobuf's classes only name what callers pass
    from google.protobuf.descriptor import EnumDescriptor
    from google.protobuf.message import Message

WIRE_VARINT, WIRE_FIXED64, WIRE_BYTES, WIRE_FIXED32 = 0, 1, 2, 5


def message_bytes(message: Message | bytes | bytearray | memoryview) -> np.ndarray:
    """The wire bytes of a message (or bytes, or any buffer, as they are), as uint8 `(num_bytes,)` for the
    walks."""
    return np.frombuffer(message.SerializeToString() if hasattr(message, "SerializeToString") else message, np.uint8)


def enum_size(enum_descriptor: EnumDescriptor) -> int:
    """n for a closed enum whose values are 0 to n - 1 (`scalar_fields`'s `enum_sizes`)."""
    numbers = sorted(v.number for v in enum_descriptor.values)
    if numbers != list(range(len(numbers))):
        raise ValueError(f"{enum_descriptor.full_name}: values are not 0 to n - 1")
    return len(numbers)


def whole(data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The span of the top-level message: (starts, ends) int64 `(1,)`."""
    return np.zeros(1, np.int64), np.full(1, len(data), np.int64)


# The helpers of the walks are inlined: a call per field (to a function that may raise) costs 20 times
# the field's work (measured).
@numba.njit(inline="always")
def _varint(data: Any, pos: Any, end: Any) -> Any:
    """(value as int64, two's complement for negative int32/int64 fields; next offset)."""
    if pos < end and data[pos] < 0x80:  # one byte: keys, lengths of small messages, flags, enums
        return np.int64(data[pos]), pos + 1
    return _long_varint(data, pos, end)


@numba.njit(inline="always")
def _long_varint(data: Any, pos: Any, end: Any) -> Any:
    value = np.uint64(0)
    shift = np.uint64(0)
    while True:
        if pos >= end or shift > 63:
            raise ValueError("protobuf wire data: a truncated or overlong varint")
        byte = data[pos]
        pos += 1
        value |= np.uint64(byte & 0x7F) << shift
        shift += np.uint64(7)
        if byte < 0x80:
            return np.int64(value), pos


@numba.njit(inline="always")
def _value_end(data: Any, pos: Any, end: Any, wire_type: Any) -> Any:
    """The offset just past a field's value, whose key ended at `pos`."""
    if wire_type == WIRE_VARINT:
        return _varint(data, pos, end)[1]
    if wire_type == WIRE_FIXED64:
        after = pos + 8
    elif wire_type == WIRE_FIXED32:
        after = pos + 4
    elif wire_type == WIRE_BYTES:
        length, pos = _varint(data, pos, end)
        after = pos + length
        if length < 0:
            after = end + 1
    else:
        raise ValueError("protobuf wire data: an unsupported wire type (a group or a corrupt key)")
    if after > end:
        raise ValueError("protobuf wire data: a field runs past the end of its message")
    return after


@numba.njit(inline="always")
def _key(data: Any, pos: Any, end: Any) -> Any:
    """(field number, wire type, offset after the key)."""
    key, pos = _varint(data, pos, end)
    if key >> 3 == 0:
        raise ValueError("protobuf wire data: field number 0")
    return key >> 3, key & 7, pos


def _aligned(data: np.ndarray) -> Any:
    """The bytes as float64 and float32 arrays starting at each offset modulo 8 and 4, so that a compiled
    walk reads the value at any offset `pos` as `f64[pos % 8][pos // 8]` (no copy)."""
    if len(data) < 8:  # too short to hold a double at every offset (read-only, as the walks' other arrays)
        data = np.frombuffer(data.tobytes() + bytes(8), np.uint8)
    f64 = tuple(np.frombuffer(data, np.float64, (len(data) - s) // 8, s) for s in range(8))
    f32 = tuple(np.frombuffer(data, np.float32, (len(data) - s) // 4, s) for s in range(4))
    return f64, f32


@numba.njit(inline="always")
def _slots(numbers: Any) -> Any:
    """Field number -> column in `numbers` (-1 for the others)."""
    slot = np.full(numbers.max() + 1 if numbers.shape[0] else 1, -1, np.int64)
    for j in range(numbers.shape[0]):
        slot[numbers[j]] = j
    return slot


@numba.njit(cache=True)
def _spans_of(
    data: Any,
    starts: Any,
    ends: Any,
    numbers: Any,
    out_start: Any,
    out_end: Any,
    out_parent: Any,
    fill: Any,
) -> Any:
    """Counts (and, with `fill`, records) the occurrences of the length-delimited fields `numbers`."""
    slot = _slots(numbers)
    n = 0
    for i in range(starts.shape[0]):
        pos, end = starts[i], ends[i]
        while pos < end:
            field, wire_type, pos = _key(data, pos, end)
            after = _value_end(data, pos, end, wire_type)
            if field < slot.shape[0] and slot[field] >= 0 and wire_type == WIRE_BYTES:
                if fill:
                    out_start[n] = _varint(data, pos, end)[1]
                    out_end[n] = after
                    out_parent[n] = i
                n += 1
            pos = after
    return n


def message_spans(
    data: np.ndarray, starts: np.ndarray, ends: np.ndarray, numbers: int | tuple[int, ...] | np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every occurrence of the length-delimited fields `numbers` (one number, or several: a oneof's) in
    each parent message, in wire order.

    Args:
      data: uint8 `(num_bytes,)`; starts, ends: int64 `(num_records,)`, the parents' spans in it.
    Returns:
      (start, end, parent): int64 `(num_values,)`, the values' spans and the index of their parent.
    """
    return _message_spans(data, starts, ends, np.atleast_1d(np.asarray(numbers, np.int64)))


@numba.njit(cache=True)
def _message_spans(data: Any, starts: Any, ends: Any, numbers: Any) -> Any:
    empty = np.empty(0, np.int64)
    n = _spans_of(data, starts, ends, numbers, empty, empty, empty, False)
    out_start, out_end, out_parent = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    _spans_of(data, starts, ends, numbers, out_start, out_end, out_parent, True)
    return out_start, out_end, out_parent


def scalar_fields(
    data: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    numbers: np.ndarray,
    wire_types: np.ndarray,
    enum_sizes: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scalar fields `numbers` (declared with `wire_types`) of each record, the last occurrence winning.

    `enum_sizes`: for a field of a closed (proto2) enum whose values are 0 to n - 1, n; 0 for other
    fields. An enum value outside that range is an unknown field, as a parse keeps it (the field
    keeps its earlier value).

    Args:
      data: uint8 `(num_bytes,)`; starts, ends: int64 `(num_records,)`; numbers, wire_types, enum_sizes:
        int64 `(num_fields,)`.
    Returns:
      (real float64 `(num_records, num_fields)`: fixed64 as double, fixed32 as float; integer int64, the
      varints (negative int32/int64 values as they are); present bool: where the field occurs).
      Fields absent from a record read as 0.
    """
    f64, f32 = _aligned(data)
    return _scalar_fields(
        data,
        f64,
        f32,
        starts,
        ends,
        np.asarray(numbers, np.int64),
        np.asarray(wire_types, np.int64),
        np.asarray(enum_sizes, np.int64),
    )


@numba.njit(cache=True)
def _scalar_fields(
    data: Any,
    f64: Any,
    f32: Any,
    starts: Any,
    ends: Any,
    numbers: Any,
    wire_types: Any,
    enum_sizes: Any,
) -> Any:
    n, m = starts.shape[0], numbers.shape[0]
    real = np.zeros((n, m), np.float64)
    integer = np.zeros((n, m), np.int64)
    present = np.zeros((n, m), np.bool_)
    slot = _slots(numbers)
    for i in range(n):
        pos, end = starts[i], ends[i]
        while pos < end:
            # The field step is written out in each walk: shared through an inlined helper returning
            # it, the walks ran 2-3x slower (measured on the real scene's track states).
            field, wire_type, pos = _key(data, pos, end)
            after = _value_end(data, pos, end, wire_type)
            j = slot[field] if field < slot.shape[0] else -1
            if j >= 0 and wire_types[j] == wire_type:
                if wire_type == WIRE_VARINT:
                    value = _varint(data, pos, end)[0]
                    if enum_sizes[j] and not 0 <= value < enum_sizes[j]:
                        pos = after
                        continue
                    integer[i, j] = value
                elif wire_type == WIRE_FIXED64:
                    real[i, j] = f64[pos % 8][pos // 8]
                elif wire_type == WIRE_FIXED32:
                    real[i, j] = f32[pos % 4][pos // 4]
                present[i, j] = True
            pos = after
    return real, integer, present


@numba.njit(inline="always")
def _any_finite_non_positive(block: Any) -> bool:
    for v in block:  # noqa: SIM110 - numba compiles loops, not `any(generator)`
        if np.isfinite(v) and v <= 0:
            return True
    return False


def float_fields(
    data: np.ndarray, starts: np.ndarray, ends: np.ndarray, numbers: np.ndarray, num_values: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The repeated float fields `numbers` of each record (packed or not), their first `num_values` values.

    Returns:
      (values float32 `(num_records, num_fields, num_values)`, 0 beyond a field's count; count int64
      `(num_records, num_fields)`: the values each field holds; non_finite, non_positive bool
      `(num_records, num_fields)`: whether any of them is NaN or infinite, or finite and <= 0).
    """
    return _float_fields(data, _aligned(data)[1], starts, ends, np.asarray(numbers, np.int64), num_values)


@numba.njit(cache=True)
def _float_fields(data: Any, f32: Any, starts: Any, ends: Any, numbers: Any, num_values: Any) -> Any:
    n, m = starts.shape[0], numbers.shape[0]
    values = np.zeros((n, m, num_values), np.float32)
    count = np.zeros((n, m), np.int64)
    non_finite = np.zeros((n, m), np.bool_)
    non_positive = np.zeros((n, m), np.bool_)
    slot = _slots(numbers)
    for i in range(n):
        pos, end = starts[i], ends[i]
        while pos < end:
            field, wire_type, pos = _key(data, pos, end)  # (see `_scalar_fields`)
            after = _value_end(data, pos, end, wire_type)
            j = slot[field] if field < slot.shape[0] else -1
            first = pos
            if j < 0 or wire_type not in (WIRE_BYTES, WIRE_FIXED32):
                pos = after
                continue
            if wire_type == WIRE_BYTES:  # packed
                first = _varint(data, pos, end)[1]
                if (after - first) % 4:
                    raise ValueError("protobuf wire data: a packed float field of a length not a multiple of 4")
            block = f32[first % 4][first // 4 : first // 4 + (after - first) // 4]
            c = count[i, j]
            take = min(max(num_values - c, 0), block.shape[0])
            values[i, j, c : c + take] = block[:take]
            count[i, j] = c + block.shape[0]
            finite, positive = True, True
            for v in block:  # branch-free, vectorised; one loop with both flags ran 2x slower
                finite &= np.isfinite(v)
                positive &= not v <= 0
            non_finite[i, j] |= not finite
            non_positive[i, j] |= not positive and _any_finite_non_positive(block)
            pos = after
    return values, count, non_finite, non_positive


def bool_fields(data: np.ndarray, starts: np.ndarray, ends: np.ndarray, number: int) -> tuple[np.ndarray, np.ndarray]:
    """The repeated bool field `number` of each record (packed or not), as a parse reads it (a varint, true
    unless 0).

    Returns:
      (count int64 `(num_records,)`: the values it holds; any_false bool `(num_records,)`: whether one is false).
    """
    return _bool_fields(data, starts, ends, np.int64(number))


@numba.njit(cache=True)
def _bool_fields(data: Any, starts: Any, ends: Any, number: Any) -> Any:
    n = starts.shape[0]
    count = np.zeros(n, np.int64)
    any_false = np.zeros(n, np.bool_)
    for i in range(n):
        pos, end = starts[i], ends[i]
        while pos < end:
            field, wire_type, pos = _key(data, pos, end)  # (see `_scalar_fields`)
            after = _value_end(data, pos, end, wire_type)
            if field == number and wire_type == WIRE_VARINT:
                count[i] += 1
                any_false[i] |= _varint(data, pos, end)[0] == 0
            elif field == number and wire_type == WIRE_BYTES:  # packed
                value_pos = _varint(data, pos, end)[1]
                while value_pos < after:
                    value, value_pos = _varint(data, value_pos, after)
                    count[i] += 1
                    any_false[i] |= value == 0
            pos = after
    return count, any_false


def compile_walks() -> None:
    """Compiles the walks now (or loads them from numba's cache), for the argument types scoring and
    validation pass: called by `scoring.warm_up.compile_loops` (and validation's pools)."""
    message = varint((1 << 3) | WIRE_BYTES) + varint(10) + varint((2 << 3) | WIRE_BYTES) + varint(8) + bytes(8)
    data = message_bytes(message)
    start, end, _ = message_spans(data, *whole(data), 1)
    scalar_fields(data, start, end, np.array([1]), np.array([WIRE_VARINT]), np.array([0]))
    float_fields(data, start, end, np.array([2]), 2)
    bool_fields(data, start, end, 2)
    rollouts_census(message, 0, len(message), 0, 10, 1, 1)


# `rollouts_census`'s outcomes: counted within the limits, or the first limit passed.
CENSUS_OK, CENSUS_MESSAGES, CENSUS_JOINT_SCENES, CENSUS_OBJECTS = 0, 1, 2, 3


def rollouts_census(
    data: bytes, start: int, end: int, messages: int, budget: int, max_joint_scenes: int, max_objects: int
) -> tuple[int, int, int, int]:
    """Counts the messages of one serialized `ScenarioRollouts`, data[start:end], and of its joint scenes, as
    `parse.limits` counts them (every field of both levels is one message), stopping at the first limit passed.

    The walk is lenient, not a parse: malformed bytes end a level's walk (the parser reports them).

    Args:
      data: the bytes (any buffer); messages: those counted before it in the shard; budget: the shard's.
    Returns:
      (messages counted so far, outcome: one of CENSUS_*, the joint scene at fault (-1: the scenario's own
      level), the byte span of the level whose field passed the message budget).
    """
    return _rollouts_census(np.frombuffer(data, np.uint8), start, end, messages, budget, max_joint_scenes, max_objects)


@numba.njit(inline="always")
def _census_key(data: Any, pos: Any, end: Any) -> Any:
    """The lenient key step: (field number, -1 for one past 2^60; wire type; next offset)."""
    key, shift, big = 0, 0, False
    while True:
        byte = np.int64(data[pos])
        if shift == 63:
            big |= (byte & 0x7F) != 0  # the key has bits past the 64th: no field number of ours
        else:
            key |= (byte & 0x7F) << shift
        pos += 1
        if not byte & 0x80 or pos >= end or shift > 56:
            break
        shift += 7
    return (-1 if big else key >> 3), key & 7, pos


@numba.njit(inline="always")
def _census_value(data: Any, pos: Any, end: Any, wire_type: Any) -> Any:
    """The lenient value step: (value start, value end, next offset), or next offset -1 where the walk stops."""
    if wire_type == WIRE_BYTES:
        length, shift, big = 0, 0, False
        while pos < end:
            byte = np.int64(data[pos])
            if shift == 63:
                big |= (byte & 0x7F) != 0
            else:
                length |= (byte & 0x7F) << shift
            pos += 1
            if not byte & 0x80 or shift > 56:
                break
            shift += 7
        if big or length > end - pos:
            return pos, pos, -1
        return pos, pos + length, pos + length
    if wire_type == WIRE_VARINT:
        while pos < end and data[pos] & 0x80:
            pos += 1
        return pos, pos, pos + 1
    if wire_type == WIRE_FIXED64:
        return pos, pos, pos + 8
    if wire_type == WIRE_FIXED32:
        return pos, pos, pos + 4
    return pos, pos, -1


@numba.njit(cache=True)
def _rollouts_census(
    data: Any,
    start: int,
    end: int,
    messages: Any,
    budget: Any,
    max_joint_scenes: Any,
    max_objects: Any,
) -> Any:
    pos, joint_scenes = start, 0
    while pos < end:
        number, wire_type, pos = _census_key(data, pos, end)
        messages += 1
        if messages > budget:
            return messages, CENSUS_MESSAGES, -1, end - start
        j_start, j_end, pos = _census_value(data, pos, end, wire_type)
        if pos < 0:
            break
        if wire_type != WIRE_BYTES or number != 2:  # ScenarioRollouts.joint_scenes
            continue
        joint_scenes += 1
        if joint_scenes > max_joint_scenes:
            return messages, CENSUS_JOINT_SCENES, joint_scenes - 1, 0
        objects, at = 0, j_start
        while at < j_end:
            number, wire_type, at = _census_key(data, at, j_end)
            messages += 1
            if messages > budget:
                return messages, CENSUS_MESSAGES, joint_scenes - 1, j_end - j_start
            _, _, at = _census_value(data, at, j_end, wire_type)
            if at < 0:
                break
            if wire_type == WIRE_BYTES:
                objects += number == 1  # JointScene.simulated_trajectories
                if objects > max_objects:
                    return messages, CENSUS_OBJECTS, joint_scenes - 1, 0
    return messages, CENSUS_OK, -1, 0
